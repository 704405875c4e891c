//! Reading camera frames from image files (PNG, JPEG, PGM/PPM) as the detectors' grayscale
//! images, with named errors for files that are not images.

use algorithms::vision::image::{FrameError, GrayImage};
use std::path::{Path, PathBuf};

/// Why an image file could not be read (or, in tests, written).
#[derive(Debug, thiserror::Error)]
pub enum FrameFileError {
    #[error("{}: cannot open: {source}", path.display())]
    Open {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: cannot read: {source}", path.display())]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: not a readable image: {source}", path.display())]
    Decode {
        path: PathBuf,
        #[source]
        source: image::ImageError,
    },
    #[error("{}: {source}", path.display())]
    Frame {
        path: PathBuf,
        #[source]
        source: FrameError,
    },
    #[cfg(test)]
    #[error("{}: frame buffer has the wrong size", path.display())]
    WrongSize { path: PathBuf },
    #[cfg(test)]
    #[error("{}: cannot write: {source}", path.display())]
    Write {
        path: PathBuf,
        #[source]
        source: image::ImageError,
    },
}

/// Loads an image file and converts it to 8-bit grayscale.
pub fn load_gray(path: &Path) -> Result<GrayImage, FrameFileError> {
    let path_buf = || path.to_path_buf();
    let decoded = image::ImageReader::open(path)
        .map_err(|source| FrameFileError::Open {
            path: path_buf(),
            source,
        })?
        .with_guessed_format()
        .map_err(|source| FrameFileError::Read {
            path: path_buf(),
            source,
        })?
        .decode()
        .map_err(|source| FrameFileError::Decode {
            path: path_buf(),
            source,
        })?;
    let luma = decoded.into_luma8();
    let (width, height) = (luma.width() as usize, luma.height() as usize);
    GrayImage::from_vec(width, height, luma.into_raw()).map_err(|source| FrameFileError::Frame {
        path: path_buf(),
        source,
    })
}

/// Writes a grayscale image as PNG (or PGM with a `.pgm` extension).
#[cfg(test)]
pub fn save_gray(path: &Path, frame: &GrayImage) -> Result<(), FrameFileError> {
    let buffer = image::GrayImage::from_raw(
        frame.width() as u32,
        frame.height() as u32,
        frame.data().to_vec(),
    )
    .ok_or_else(|| FrameFileError::WrongSize {
        path: path.to_path_buf(),
    })?;
    buffer.save(path).map_err(|source| FrameFileError::Write {
        path: path.to_path_buf(),
        source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_round_trip_through_png_and_pgm() {
        let dir = tempfile::tempdir().unwrap();
        let data: Vec<u8> = (0..12 * 7).map(|i| (i * 3 % 256) as u8).collect();
        let frame = GrayImage::from_vec(12, 7, data).unwrap();
        for name in ["frame.png", "frame.pgm"] {
            let path = dir.path().join(name);
            save_gray(&path, &frame).unwrap();
            assert_eq!(load_gray(&path).unwrap(), frame);
        }
    }

    #[test]
    fn a_file_that_is_not_an_image_is_a_named_error() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("notes.png");
        std::fs::write(&path, "not an image").unwrap();
        let message = load_gray(&path).unwrap_err().to_string();
        assert!(message.contains("not a readable image"), "{message}");
        let missing = load_gray(&dir.path().join("missing.png"))
            .unwrap_err()
            .to_string();
        assert!(missing.contains("cannot open"), "{missing}");
    }
}
