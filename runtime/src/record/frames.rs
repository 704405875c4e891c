//! Camera frames in a recording. A kept frame is a lossless `foxglove.CompressedImage`: by
//! default in qosrt's compact codec ([`super::gray_codec`], format `qosrt-gray`), or as a PNG,
//! which Foxglove shows as it is (the live view always gets PNGs); the replay gets every pixel
//! back either way. Under `frames = "consumed"`
//! a frame no task read is kept as its size alone (`/camera/unread`): the replay delivers a
//! blank frame in its place, so the tasks, the topic's counts and the measured camera rate see
//! what they saw in flight.
//!
//! PNG at its fastest deflate with the Paeth filter on every row: on the reference mission's
//! 640×480 frames it keeps 0.56 of the raw bytes, smaller than deflate's strongest setting
//! (0.57) at a fortieth of the time; choosing each row's filter (0.55) costs half as much again
//! on the recorder's thread. Those frames carry the camera's noise, which PNG's filters and
//! deflate's codes do not model: the compact codec keeps 0.48.

use super::channels::{timestamp, ChannelError};
use super::gray_codec;
use super::FrameCodec;
use algorithms::vision::image::GrayImage;
use foxglove::messages as fg;
use image::codecs::png::{CompressionType, FilterType, PngDecoder, PngEncoder};
use image::{ImageDecoder, ImageEncoder};
use prost::Message as _;
use serde::{Deserialize, Serialize};

/// The `foxglove.CompressedImage` format of the compact codec's frames.
pub const COMPACT_FORMAT: &str = "qosrt-gray";

/// A grayscale frame as `codec` stores it, stamped at its capture.
pub fn encode_frame(codec: FrameCodec, image: &GrayImage, capture_ns: u64) -> Vec<u8> {
    match codec {
        FrameCodec::Raw => super::channels::gray_image(image, capture_ns),
        FrameCodec::Png => png_image(image, capture_ns),
        FrameCodec::Compact => compressed_image(
            capture_ns,
            gray_codec::encode(image.width(), image.height(), image.data()),
            COMPACT_FORMAT,
        ),
    }
}

fn compressed_image(capture_ns: u64, data: Vec<u8>, format: &str) -> Vec<u8> {
    fg::CompressedImage {
        timestamp: Some(timestamp(capture_ns)),
        frame_id: "camera".into(),
        data: data.into(),
        format: format.into(),
    }
    .encode_to_vec()
}

/// A grayscale frame as a lossless PNG in `foxglove.CompressedImage`, stamped at its capture.
pub fn png_image(image: &GrayImage, capture_ns: u64) -> Vec<u8> {
    let png = png_bytes(image.width(), image.height(), image.data());
    compressed_image(capture_ns, png, "png")
}

fn png_bytes(width: usize, height: usize, pixels: &[u8]) -> Vec<u8> {
    let mut png = Vec::with_capacity(pixels.len() / 2);
    PngEncoder::new_with_quality(&mut png, CompressionType::Fast, FilterType::Paeth)
        .write_image(
            pixels,
            width as u32,
            height as u32,
            image::ExtendedColorType::L8,
        )
        .expect("a grey image of its own size encodes into memory");
    png
}

/// The grayscale frame a `foxglove.CompressedImage` holds as an 8-bit grey PNG.
pub fn decode_png_image(bytes: &[u8]) -> Result<GrayImage, ChannelError> {
    let message = compressed_image_in(bytes, "png")?;
    let decoder = PngDecoder::new(std::io::Cursor::new(&message.data[..]))?;
    if decoder.color_type() != image::ColorType::L8 {
        return Err(ChannelError::ImageFormat {
            expected: "png",
            found: format!("png of {:?} pixels, not 8-bit grey", decoder.color_type()),
        });
    }
    let (width, height) = decoder.dimensions();
    let mut pixels = vec![0; decoder.total_bytes() as usize];
    decoder.read_image(&mut pixels)?;
    Ok(GrayImage::from_vec(
        width as usize,
        height as usize,
        pixels,
    )?)
}

/// A `foxglove.CompressedImage` whose image is in `format`.
fn compressed_image_in(
    bytes: &[u8],
    format: &'static str,
) -> Result<fg::CompressedImage, ChannelError> {
    let message = fg::CompressedImage::decode(bytes).map_err(ChannelError::NotCompressedImage)?;
    if message.format != format {
        return Err(ChannelError::ImageFormat {
            expected: format,
            found: message.format,
        });
    }
    Ok(message)
}

/// A recorded camera frame as the recording's codec stored it.
pub fn decode_frame(codec: FrameCodec, bytes: &[u8]) -> Result<GrayImage, ChannelError> {
    match codec {
        FrameCodec::Raw => super::channels::decode_gray_image(bytes),
        FrameCodec::Png => decode_png_image(bytes),
        FrameCodec::Compact => {
            let message = compressed_image_in(bytes, COMPACT_FORMAT)?;
            let (width, height, pixels) = gray_codec::decode(&message.data)?;
            Ok(GrayImage::from_vec(width, height, pixels)?)
        }
    }
}

/// A frame the runner delivered and no task read: its size, for the blank frame a replay
/// delivers in its place (its index is the message's sequence, its capture the publish time).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct UnreadFrame {
    pub width_px: u32,
    pub height_px: u32,
}

impl UnreadFrame {
    pub fn of(image: &GrayImage) -> Self {
        Self {
            width_px: image.width() as u32,
            height_px: image.height() as u32,
        }
    }

    /// The blank frame a replay delivers in its place.
    pub fn blank(&self) -> Result<GrayImage, ChannelError> {
        let (width, height) = (self.width_px as usize, self.height_px as usize);
        Ok(GrayImage::from_vec(width, height, vec![0; width * height])?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn noisy(width: usize, height: usize) -> GrayImage {
        // A gradient with pseudo-random noise: what the simulated camera renders.
        let pixels = (0..width * height)
            .map(|i| ((i % width) / 3 + (i * 2_654_435_761 % 97)) as u8)
            .collect();
        GrayImage::from_vec(width, height, pixels).unwrap()
    }

    #[test]
    fn a_png_frame_comes_back_pixel_for_pixel_and_smaller() {
        let frame = noisy(64, 48);
        let encoded = png_image(&frame, 7);
        assert!(
            encoded.len() < frame.data().len(),
            "{} bytes",
            encoded.len()
        );
        let back = decode_frame(FrameCodec::Png, &encoded).unwrap();
        assert_eq!((back.width(), back.height()), (64, 48));
        assert_eq!(back.data(), frame.data());
        // Foxglove reads it: the stamp and the format a viewer needs.
        let message = fg::CompressedImage::decode(&encoded[..]).unwrap();
        assert_eq!(message.format, "png");
        assert_eq!(message.timestamp.unwrap().nsec(), 7);
        // The codecs are not each other's.
        assert!(decode_frame(FrameCodec::Raw, &encoded).is_err());
        let raw = super::super::channels::gray_image(&frame, 7);
        assert!(decode_frame(FrameCodec::Png, &raw).is_err());
    }

    #[test]
    fn a_compressed_image_that_is_not_a_grey_png_is_named() {
        let jpeg = fg::CompressedImage {
            format: "jpeg".into(),
            ..Default::default()
        }
        .encode_to_vec();
        assert!(matches!(
            decode_png_image(&jpeg),
            Err(ChannelError::ImageFormat { found, .. }) if found == "jpeg"
        ));
        let mut rgb = Vec::new();
        PngEncoder::new(&mut rgb)
            .write_image(&[1, 2, 3, 4, 5, 6], 2, 1, image::ExtendedColorType::Rgb8)
            .unwrap();
        let message = fg::CompressedImage {
            format: "png".into(),
            data: rgb.into(),
            ..Default::default()
        }
        .encode_to_vec();
        let error = decode_png_image(&message).unwrap_err();
        assert!(error.to_string().contains("not 8-bit grey"), "{error}");
        let cut = fg::CompressedImage {
            format: "png".into(),
            data: png_image(&noisy(16, 16), 0)[..40].to_vec().into(),
            ..Default::default()
        }
        .encode_to_vec();
        assert!(matches!(decode_png_image(&cut), Err(ChannelError::Png(_))));
    }

    #[test]
    fn a_compact_frame_comes_back_pixel_for_pixel() {
        let frame = noisy(64, 48);
        let compact = encode_frame(FrameCodec::Compact, &frame, 7);
        let message = fg::CompressedImage::decode(&compact[..]).unwrap();
        assert_eq!(message.format, COMPACT_FORMAT);
        assert_eq!(message.timestamp.unwrap().nsec(), 7);
        let back = decode_frame(FrameCodec::Compact, &compact).unwrap();
        assert_eq!(back.data(), frame.data());
        let as_png = encode_frame(FrameCodec::Png, &frame, 7);
        // A frame under the other codec's name is refused, naming both.
        let error = decode_frame(FrameCodec::Compact, &as_png).unwrap_err();
        assert!(
            error.to_string().contains("qosrt-gray, found png"),
            "{error}"
        );
        let mut cut = message.clone();
        cut.data = cut.data.slice(..20);
        assert!(matches!(
            decode_frame(FrameCodec::Compact, &cut.encode_to_vec()),
            Err(ChannelError::Compact(_))
        ));
    }

    #[test]
    fn an_unread_frame_becomes_a_blank_one_of_its_size() {
        let unread = UnreadFrame::of(&noisy(20, 10));
        let blank = unread.blank().unwrap();
        assert_eq!((blank.width(), blank.height()), (20, 10));
        assert!(blank.data().iter().all(|&p| p == 0));
    }
}
