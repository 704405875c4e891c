//! `qosrt detect`: the landing-marker detector on image files, so people (and scripts) can try
//! it on their own camera's frames.

use crate::check::EXIT_INVALID_CONFIG;
use crate::frames::load_gray;
use algorithms::vision::aruco::{ArucoConfig, ArucoDetector, ArucoError};
use algorithms::vision::landing_marker::{
    ArucoSeen, LandingMarkerConfig, LandingMarkerDetector, LandingMarkerError, LandingMarkerLayout,
    LandingMarkerObservation, NfoldSeen,
};
use algorithms::vision::nfold::{NfoldConfigError, NfoldDetector};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[derive(Serialize)]
struct FileReport {
    file: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    error: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    width_px: Option<usize>,
    #[serde(skip_serializing_if = "Option::is_none")]
    height_px: Option<usize>,
    /// The strongest n-fold marker in the whole frame.
    #[serde(skip_serializing_if = "Option::is_none")]
    nfold: Option<NfoldSeen>,
    /// Every ArUco marker of the layout's dictionary in the frame.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    aruco: Vec<ArucoSeen>,
    /// The pad, from the parts of the layout seen.
    #[serde(skip_serializing_if = "Option::is_none")]
    landing_marker: Option<LandingMarkerObservation>,
}

struct Detectors {
    nfold: NfoldDetector,
    aruco: ArucoDetector,
    landing_marker: LandingMarkerDetector,
}

pub fn run(images: &[PathBuf], layout: Option<&Path>, json: bool) -> ExitCode {
    let mut detectors = match detectors(layout) {
        Ok(detectors) => detectors,
        Err(message) => {
            eprintln!("error: {message}");
            return ExitCode::from(EXIT_INVALID_CONFIG);
        }
    };
    let reports: Vec<FileReport> = images
        .iter()
        .map(|path| detect_file(&mut detectors, path))
        .collect();
    crate::output::print_result(json, &reports, |reports| {
        reports.iter().map(human).collect()
    });
    if reports.iter().any(|r| r.error.is_some()) {
        for report in reports.iter().filter(|r| r.error.is_some()) {
            eprintln!("error: {}", report.error.as_deref().unwrap_or_default());
        }
        ExitCode::from(EXIT_INVALID_CONFIG)
    } else {
        ExitCode::SUCCESS
    }
}

/// Why the detectors could not be set up from the layout.
#[derive(Debug, thiserror::Error)]
enum LayoutError {
    #[error("{path}: cannot read the layout: {source}")]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}:{line}:{column}: {}", source.message())]
    Parse {
        path: PathBuf,
        line: usize,
        column: usize,
        #[source]
        source: Box<toml::de::Error>,
    },
    #[error(transparent)]
    Marker(#[from] LandingMarkerError),
    #[error("the n-fold detector: {0}")]
    Nfold(#[from] NfoldConfigError),
    #[error("the ArUco detector: {0}")]
    Aruco(#[from] ArucoError),
}

fn detectors(layout_path: Option<&Path>) -> Result<Detectors, LayoutError> {
    let layout = match layout_path {
        None => LandingMarkerLayout::default(),
        Some(path) => {
            let text = std::fs::read_to_string(path).map_err(|source| LayoutError::Read {
                path: path.to_path_buf(),
                source,
            })?;
            toml::from_str(&text).map_err(|source| {
                let (line, column) = source
                    .span()
                    .map(|s| runtime::diagnostic::line_col(&text, s.start))
                    .unwrap_or((1, 1));
                LayoutError::Parse {
                    path: path.to_path_buf(),
                    line,
                    column,
                    source: Box::new(source),
                }
            })?
        }
    };
    let dictionary = layout.validate()?;
    let mut config = LandingMarkerConfig {
        layout,
        ..LandingMarkerConfig::default()
    };
    config.nfold.order = config.layout.nfold_order;
    config.nfold.oriented = config.layout.nfold_oriented;
    Ok(Detectors {
        nfold: NfoldDetector::new(config.nfold.clone())?,
        aruco: ArucoDetector::new(dictionary, ArucoConfig::default())?,
        landing_marker: LandingMarkerDetector::new(config)?,
    })
}

fn detect_file(detectors: &mut Detectors, path: &Path) -> FileReport {
    let mut report = FileReport {
        file: path.display().to_string(),
        error: None,
        width_px: None,
        height_px: None,
        nfold: None,
        aruco: Vec::new(),
        landing_marker: None,
    };
    let frame = match load_gray(path) {
        Ok(frame) => frame,
        Err(error) => {
            report.error = Some(error.to_string());
            return report;
        }
    };
    let view = frame.view();
    report.width_px = Some(view.width());
    report.height_px = Some(view.height());
    let outcome = (|| -> Result<(), Box<dyn std::error::Error>> {
        report.nfold = detectors.nfold.detect(&view)?.map(|d| NfoldSeen {
            centre_px: [d.u_px, d.v_px],
            orientation_rad: d.orientation_rad,
            orientation_resolved: d.orientation_resolved,
            quality: d.quality,
            kernel_size_px: d.kernel_size_px,
        });
        report.aruco = detectors
            .aruco
            .detect(&view)?
            .into_iter()
            .map(|m| ArucoSeen {
                id: m.id,
                corners_px: m.corners_px.map(|(u, v)| [u, v]),
                hamming_distance: m.hamming_distance,
            })
            .collect();
        report.landing_marker = detectors.landing_marker.detect(&view, None)?;
        Ok(())
    })();
    if let Err(message) = outcome {
        report.error = Some(format!("{}: {message}", path.display()));
    }
    report
}

fn human(report: &FileReport) -> String {
    let mut out = report.file.clone();
    if let (Some(w), Some(h)) = (report.width_px, report.height_px) {
        out += &format!(" ({w}×{h})");
    }
    out += "\n";
    if let Some(error) = &report.error {
        return out + &format!("  error: {error}\n");
    }
    match &report.nfold {
        Some(n) => {
            out += &format!(
                "  n-fold: centre ({:.2}, {:.2}) px, orientation {:.1}°{}, quality {:.2}, kernel {} px\n",
                n.centre_px[0],
                n.centre_px[1],
                n.orientation_rad.to_degrees(),
                if n.orientation_resolved { "" } else { " (unresolved)" },
                n.quality,
                n.kernel_size_px
            )
        }
        None => out += "  n-fold: none\n",
    }
    for marker in &report.aruco {
        let corners: Vec<String> = marker
            .corners_px
            .iter()
            .map(|[u, v]| format!("({u:.2}, {v:.2})"))
            .collect();
        out += &format!("  ArUco {}: corners {}\n", marker.id, corners.join(" "));
    }
    match &report.landing_marker {
        Some(o) => {
            out += &format!(
                "  landing marker: centre ({:.2}, {:.2}) px from {:?}{}, ArUco ids seen {:?}\n",
                o.centre_px[0],
                o.centre_px[1],
                o.centre_from,
                o.orientation_rad
                    .map(|a| format!(", orientation {:.1}°", a.to_degrees()))
                    .unwrap_or_default(),
                o.aruco.iter().map(|a| a.id).collect::<Vec<_>>()
            )
        }
        None => out += "  landing marker: none\n",
    }
    out
}
