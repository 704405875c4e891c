//! [`ImageFolderSource`]: a folder of recorded frames (PNG, JPEG, PGM) played as a camera.

use std::fmt;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use algorithms::vision::image::GrayImage;

use super::{CameraSource, CameraSourceError, CapturedFrame};
use crate::topics::CameraFrame;

/// How an image folder is played.
#[derive(Debug, Clone, PartialEq)]
pub struct ImageFolderConfig {
    pub folder: PathBuf,
    pub rate_fps: f64,
    /// Start again from the first file after the last.
    pub looping: bool,
    /// The camera's frame size; `None` takes the first good frame's size.
    pub expected_size_px: Option<(usize, usize)>,
}

impl ImageFolderConfig {
    pub fn new(folder: impl Into<PathBuf>, rate_fps: f64) -> Self {
        Self {
            folder: folder.into(),
            rate_fps,
            looping: false,
            expected_size_px: None,
        }
    }
}

/// Plays the image files of a folder, in file-name order, at a fixed rate.
pub struct ImageFolderSource {
    name: String,
    files: Vec<PathBuf>,
    rate_fps: f64,
    looping: bool,
    expected_size_px: Option<(usize, usize)>,
    /// Clock time of the first poll: frame k is due at start + k / rate.
    start_s: Option<f64>,
    /// Frames delivered or attempted so far (the next frame's index).
    played: u64,
}

impl fmt::Debug for ImageFolderSource {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("ImageFolderSource")
            .field("name", &self.name)
            .field("files", &self.files.len())
            .field("rate_fps", &self.rate_fps)
            .field("looping", &self.looping)
            .field("played", &self.played)
            .finish()
    }
}

/// The file extensions played, lower case.
const EXTENSIONS: [&str; 6] = ["png", "jpg", "jpeg", "pgm", "pnm", "ppm"];

impl ImageFolderSource {
    /// Lists the folder's image files; fails on a missing or empty folder or a bad rate.
    pub fn open(config: ImageFolderConfig) -> Result<Self, CameraSourceError> {
        if !(config.rate_fps.is_finite() && config.rate_fps > 0.0) {
            return Err(CameraSourceError::Config {
                name: "rate_fps",
                reason: format!("must be a positive number, got {}", config.rate_fps),
            });
        }
        if let Some((width, height)) = config.expected_size_px {
            if width == 0 || height == 0 {
                return Err(CameraSourceError::Config {
                    name: "expected_size_px",
                    reason: format!("must not be empty, got {width}×{height}"),
                });
            }
        }
        let folder_error = |source: std::io::Error| CameraSourceError::Folder {
            folder: config.folder.clone(),
            source,
        };
        let mut files = Vec::new();
        for entry in std::fs::read_dir(&config.folder).map_err(folder_error)? {
            let path = entry.map_err(folder_error)?.path();
            let is_image = path
                .extension()
                .and_then(|e| e.to_str())
                .is_some_and(|e| EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()));
            if is_image && path.is_file() {
                files.push(path);
            }
        }
        if files.is_empty() {
            return Err(CameraSourceError::EmptyFolder {
                folder: config.folder,
            });
        }
        files.sort_by(|a, b| a.file_name().cmp(&b.file_name()));
        Ok(Self {
            name: format!("image folder {}", config.folder.display()),
            files,
            rate_fps: config.rate_fps,
            looping: config.looping,
            expected_size_px: config.expected_size_px,
            start_s: None,
            played: 0,
        })
    }

    /// The files played, in order.
    pub fn files(&self) -> &[PathBuf] {
        &self.files
    }

    fn load(&mut self, path: &Path) -> Result<GrayImage, CameraSourceError> {
        let image = load_gray(path)?;
        let found = (image.width(), image.height());
        let (expected_width, expected_height) = *self.expected_size_px.get_or_insert(found);
        if found != (expected_width, expected_height) {
            return Err(CameraSourceError::WrongSize {
                path: path.to_path_buf(),
                expected_width,
                expected_height,
                found_width: found.0,
                found_height: found.1,
            });
        }
        Ok(image)
    }
}

impl CameraSource for ImageFolderSource {
    fn name(&self) -> &str {
        &self.name
    }

    fn next_frame(&mut self, now_s: f64) -> Result<Option<CapturedFrame>, CameraSourceError> {
        if !now_s.is_finite() {
            return Err(CameraSourceError::Config {
                name: "now_s",
                reason: format!("the clock must be finite, got {now_s}"),
            });
        }
        let start_s = *self.start_s.get_or_insert(now_s);
        // A little tolerance so that t = k / rate counts as frame k's time despite rounding.
        let due = ((now_s - start_s) * self.rate_fps + 1e-9).floor();
        if due < self.played as f64 {
            return Ok(None);
        }
        // The end shows when the frame after the last would have been due.
        let count = self.files.len() as u64;
        if !self.looping && self.played >= count {
            return Err(CameraSourceError::Ended {
                source_name: self.name.clone(),
            });
        }
        // Every file plays once per pass, even when polled late: a recording is not skipped.
        let frame_index = self.played;
        self.played += 1;
        let path = self.files[(frame_index % count) as usize].clone();
        let image = self.load(&path)?;
        Ok(Some(CapturedFrame {
            frame: CameraFrame {
                vehicle_at_capture: None,
                frame_index,
                image: Arc::new(image),
            },
            // A recording's frames are taken as captured when they play.
            capture_time_s: start_s + frame_index as f64 / self.rate_fps,
            arrived_s: now_s,
        }))
    }
}

/// Reads an image file as 8-bit grayscale.
pub fn load_gray(path: &Path) -> Result<GrayImage, CameraSourceError> {
    let unreadable = |source: std::io::Error| CameraSourceError::Unreadable {
        path: path.to_path_buf(),
        source,
    };
    let format = |source: super::BoxedError| CameraSourceError::Format {
        path: path.to_path_buf(),
        source,
    };
    let decoded = image::ImageReader::open(path)
        .map_err(unreadable)?
        .with_guessed_format()
        .map_err(unreadable)?
        .decode()
        .map_err(|e| format(e.into()))?;
    let luma = decoded.into_luma8();
    let (width, height) = (luma.width() as usize, luma.height() as usize);
    GrayImage::from_vec(width, height, luma.into_raw()).map_err(|e| format(e.into()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write_png(path: &Path, width: u32, height: u32, level: u8) {
        image::GrayImage::from_pixel(width, height, image::Luma([level]))
            .save(path)
            .unwrap();
    }

    #[test]
    fn good_frames_play_in_order_and_bad_ones_are_named_errors() {
        let dir = tempfile::tempdir().unwrap();
        write_png(&dir.path().join("frame_00.png"), 32, 24, 10);
        write_png(&dir.path().join("frame_01.png"), 32, 24, 20);
        std::fs::write(dir.path().join("frame_02.png"), b"not a png at all").unwrap();
        write_png(&dir.path().join("frame_03.png"), 16, 24, 30);
        // PGM as well as PNG; a text file is ignored.
        image::GrayImage::from_pixel(32, 24, image::Luma([40]))
            .save(dir.path().join("frame_04.pgm"))
            .unwrap();
        std::fs::write(dir.path().join("notes.txt"), "ignored").unwrap();

        let mut source = ImageFolderSource::open(ImageFolderConfig::new(dir.path(), 10.0)).unwrap();
        assert_eq!(source.files().len(), 5);
        let mut t = 100.0;
        let mut next = |source: &mut ImageFolderSource| {
            // Nothing new between frames.
            let result = source.next_frame(t);
            assert!(matches!(source.next_frame(t + 0.05), Ok(None)));
            t += 0.1;
            result
        };
        let level = |r: Result<Option<CapturedFrame>, CameraSourceError>| {
            let captured = r.unwrap().unwrap();
            // Stamped when it was due: 10 fps from the first poll at 100 s.
            let due_s = 100.0 + captured.frame.frame_index as f64 * 0.1;
            assert!((captured.capture_time_s - due_s).abs() < 1e-9);
            (captured.frame.frame_index, captured.frame.image.get(3, 3))
        };
        assert_eq!(level(next(&mut source)), (0, 10));
        assert_eq!(level(next(&mut source)), (1, 20));
        match next(&mut source) {
            Err(CameraSourceError::Format { path, source }) => {
                assert!(path.ends_with("frame_02.png"));
                // The decoder's own error is kept as the cause.
                assert!(
                    source.downcast_ref::<image::ImageError>().is_some(),
                    "{source:?}"
                );
            }
            other => panic!("expected a format error, got {other:?}"),
        }
        assert!(matches!(
            next(&mut source),
            Err(CameraSourceError::WrongSize {
                expected_width: 32,
                found_width: 16,
                ..
            })
        ));
        // The bad frames left gaps in the index; the next good one plays.
        assert_eq!(level(next(&mut source)), (4, 40));
        // After the last file, the end is named, and stays so.
        for t in [100.5, 100.55, 101.0] {
            assert!(matches!(
                source.next_frame(t),
                Err(CameraSourceError::Ended { .. })
            ));
        }
    }

    #[test]
    fn a_looping_folder_starts_again() {
        let dir = tempfile::tempdir().unwrap();
        write_png(&dir.path().join("b.png"), 8, 8, 2);
        write_png(&dir.path().join("a.png"), 8, 8, 1);
        let config = ImageFolderConfig {
            looping: true,
            ..ImageFolderConfig::new(dir.path(), 5.0)
        };
        let mut source = ImageFolderSource::open(config).unwrap();
        let levels: Vec<u8> = (0..5)
            .map(|k| {
                let frame = source.next_frame(k as f64 * 0.2).unwrap().unwrap().frame;
                assert_eq!(frame.frame_index, k);
                frame.image.get(0, 0)
            })
            .collect();
        assert_eq!(levels, [1, 2, 1, 2, 1]);
    }

    #[test]
    fn an_expected_size_rejects_the_first_frame_too() {
        let dir = tempfile::tempdir().unwrap();
        write_png(&dir.path().join("a.png"), 8, 8, 1);
        let config = ImageFolderConfig {
            expected_size_px: Some((640, 480)),
            ..ImageFolderConfig::new(dir.path(), 5.0)
        };
        let mut source = ImageFolderSource::open(config).unwrap();
        assert!(matches!(
            source.next_frame(0.0),
            Err(CameraSourceError::WrongSize {
                expected_width: 640,
                found_width: 8,
                ..
            })
        ));
    }

    #[test]
    fn empty_or_missing_folders_and_bad_rates_are_named_errors() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("readme.md"), "no images").unwrap();
        assert!(matches!(
            ImageFolderSource::open(ImageFolderConfig::new(dir.path(), 10.0)),
            Err(CameraSourceError::EmptyFolder { .. })
        ));
        assert!(matches!(
            ImageFolderSource::open(ImageFolderConfig::new(dir.path().join("missing"), 10.0)),
            Err(CameraSourceError::Folder { .. })
        ));
        write_png(&dir.path().join("a.png"), 8, 8, 1);
        assert!(matches!(
            ImageFolderSource::open(ImageFolderConfig::new(dir.path(), 0.0)),
            Err(CameraSourceError::Config {
                name: "rate_fps",
                ..
            })
        ));
    }

    #[test]
    fn an_unreadable_file_is_a_named_error() {
        let dir = tempfile::tempdir().unwrap();
        match load_gray(&dir.path().join("gone.png")) {
            Err(CameraSourceError::Unreadable { source, .. }) => {
                assert_eq!(source.kind(), std::io::ErrorKind::NotFound)
            }
            Err(other) => panic!("expected an unreadable file, got {other:?}"),
            Ok(_) => panic!("a missing file was read"),
        }
    }
}
