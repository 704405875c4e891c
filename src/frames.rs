//! Reading camera frames from image files (PNG, JPEG, PGM/PPM) as the detectors' grayscale
//! images, with named errors for files that are not images.

use algorithms::vision::image::GrayImage;
use std::path::Path;

/// Loads an image file and converts it to 8-bit grayscale.
pub fn load_gray(path: &Path) -> Result<GrayImage, String> {
    let decoded = image::ImageReader::open(path)
        .map_err(|error| format!("{}: cannot open: {error}", path.display()))?
        .with_guessed_format()
        .map_err(|error| format!("{}: cannot read: {error}", path.display()))?
        .decode()
        .map_err(|error| format!("{}: not a readable image: {error}", path.display()))?;
    let luma = decoded.into_luma8();
    let (width, height) = (luma.width() as usize, luma.height() as usize);
    GrayImage::from_vec(width, height, luma.into_raw())
        .map_err(|error| format!("{}: {error}", path.display()))
}

/// Writes a grayscale image as PNG (or PGM with a `.pgm` extension).
#[cfg(test)]
pub fn save_gray(path: &Path, frame: &GrayImage) -> Result<(), String> {
    let buffer = image::GrayImage::from_raw(
        frame.width() as u32,
        frame.height() as u32,
        frame.data().to_vec(),
    )
    .ok_or_else(|| format!("{}: frame buffer has the wrong size", path.display()))?;
    buffer
        .save(path)
        .map_err(|error| format!("{}: cannot write: {error}", path.display()))
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
        let message = load_gray(&path).unwrap_err();
        assert!(message.contains("not a readable image"), "{message}");
        let missing = load_gray(&dir.path().join("missing.png")).unwrap_err();
        assert!(missing.contains("cannot open"), "{missing}");
    }
}
