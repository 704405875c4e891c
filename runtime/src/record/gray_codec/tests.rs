use super::*;
use image::codecs::png::{CompressionType, FilterType, PngEncoder};
use image::ImageEncoder;
use rand::{Rng, SeedableRng};

/// A camera-like frame: a shaded field, a dark square with sharp edges (a marker), and the
/// sensor's Gaussian noise of `noise_sigma` levels.
fn camera_like(width: usize, height: usize, noise_sigma: f64, seed: u64) -> Vec<u8> {
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let mut pixels = Vec::with_capacity(width * height);
    for y in 0..height {
        for x in 0..width {
            let field = 90.0 + 40.0 * ((x as f64 / 23.0).sin() * (y as f64 / 31.0).cos());
            let marker =
                (width / 3..width / 2).contains(&x) && (height / 3..height / 2).contains(&y);
            let level = if marker { 20.0 } else { field };
            // Box–Muller from two uniforms: the noise is drawn here, not by the code under test.
            let (u1, u2): (f64, f64) = (rng.random::<f64>().max(1e-12), rng.random());
            let noise = (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos();
            pixels.push((level + noise_sigma * noise).round().clamp(0.0, 255.0) as u8);
        }
    }
    pixels
}

fn round_trip(width: usize, height: usize, pixels: &[u8]) -> Vec<u8> {
    let encoded = encode(width, height, pixels);
    let (w, h, back) = decode(&encoded).expect("its own frame decodes");
    assert_eq!((w, h), (width, height));
    assert_eq!(back, pixels, "{width}×{height}: pixel for pixel");
    encoded
}

fn png_size(width: usize, height: usize, pixels: &[u8]) -> usize {
    let mut png = Vec::new();
    PngEncoder::new_with_quality(&mut png, CompressionType::Best, FilterType::Adaptive)
        .write_image(
            pixels,
            width as u32,
            height as u32,
            image::ExtendedColorType::L8,
        )
        .unwrap();
    png.len()
}

#[test]
fn every_pixel_comes_back_whatever_the_frame() {
    let mut rng = rand::rngs::StdRng::seed_from_u64(7);
    // Edges of the frame (one row, one column, one pixel), every grey level, uniform noise
    // (every residual), constant frames (no bits at all) and camera-like frames.
    for (width, height) in [(1, 1), (1, 9), (9, 1), (2, 2), (3, 5), (64, 48), (17, 3)] {
        let noise: Vec<u8> = (0..width * height).map(|_| rng.random()).collect();
        round_trip(width, height, &noise);
        round_trip(width, height, &vec![0; width * height]);
        round_trip(width, height, &vec![255; width * height]);
        round_trip(width, height, &camera_like(width, height, 2.0, 3));
    }
    let levels: Vec<u8> = (0..=255).collect();
    round_trip(16, 16, &levels);
    // Alternating extremes: residuals of ±255 wrap around modulo 256.
    let checkers: Vec<u8> = (0..32 * 32)
        .map(|i| if (i / 32 + i % 32) % 2 == 0 { 0 } else { 255 })
        .collect();
    round_trip(32, 32, &checkers);
}

#[test]
fn a_camera_frame_is_smaller_than_png_at_its_strongest_and_above_the_noise_entropy() {
    let (width, height, sigma) = (320, 240, 2.0);
    let pixels = camera_like(width, height, sigma, 11);
    let encoded = round_trip(width, height, &pixels);
    let png = png_size(width, height, &pixels);
    assert!(
        (encoded.len() as f64) < 0.95 * png as f64,
        "compact {} bytes against PNG's strongest {png}",
        encoded.len()
    );
    // No lossless code can go below the noise's own entropy: a rounded Gaussian of σ = 2
    // holds ½·log2(2πe·σ²) = 3.05 bits a pixel.
    let floor_bits =
        0.5 * (2.0 * std::f64::consts::PI * std::f64::consts::E * sigma * sigma).log2();
    let bits_per_pixel = encoded.len() as f64 * 8.0 / (width * height) as f64;
    assert!(
        bits_per_pixel > floor_bits && bits_per_pixel < floor_bits + 1.5,
        "{bits_per_pixel:.2} bits a pixel, the noise holds {floor_bits:.2}"
    );
}

#[test]
fn a_constant_frame_costs_next_to_nothing() {
    // Only the first rows, predicted from the mid-grey above the frame, cost bits.
    let encoded = round_trip(640, 480, &vec![77; 640 * 480]);
    assert!(encoded.len() < 640 * 480 / 256, "{} bytes", encoded.len());
}

#[test]
fn a_cut_or_damaged_frame_is_an_error_never_a_panic() {
    let (width, height) = (40, 30);
    let encoded = encode(width, height, &camera_like(width, height, 2.0, 5));
    for cut in 0..encoded.len() {
        assert!(
            decode(&encoded[..cut]).is_err(),
            "cut at {cut} of {}",
            encoded.len()
        );
    }
    let mut longer = encoded.clone();
    longer.extend_from_slice(&[0, 0]);
    assert_eq!(decode(&longer), Err(GrayCodecError::Corrupt));
    assert_eq!(
        decode(b"\x89PNG\r\n\x1a\n"),
        Err(GrayCodecError::NotGrayFrame)
    );
    let mut rng = rand::rngs::StdRng::seed_from_u64(9);
    let mut corrupt_found = 0;
    for _ in 0..2000 {
        let mut damaged = encoded.clone();
        let at = rng.random_range(4..damaged.len());
        damaged[at] ^= 1 << rng.random_range(0..8);
        // A flipped bit in the pixels' words may still decode to other pixels; it must not
        // panic, and the state check finds nearly all.
        if decode(&damaged).is_err() {
            corrupt_found += 1;
        }
    }
    assert!(
        corrupt_found > 1900,
        "{corrupt_found} of 2000 damaged frames found"
    );
}

#[test]
fn a_malformed_header_or_table_is_named() {
    let mut header = MAGIC.to_vec();
    header.extend_from_slice(&0u32.to_le_bytes());
    header.extend_from_slice(&5u32.to_le_bytes());
    assert_eq!(
        decode(&header),
        Err(GrayCodecError::BadSize {
            width: 0,
            height: 5
        })
    );
    let mut huge = MAGIC.to_vec();
    huge.extend_from_slice(&65536u32.to_le_bytes());
    huge.extend_from_slice(&65536u32.to_le_bytes());
    assert!(matches!(decode(&huge), Err(GrayCodecError::BadSize { .. })));
    // A one-symbol table that does not sum to 2^12.
    let mut short_sum = MAGIC.to_vec();
    short_sum.extend_from_slice(&4u32.to_le_bytes());
    short_sum.extend_from_slice(&4u32.to_le_bytes());
    write_varint(&mut short_sum, 1);
    write_varint(&mut short_sum, 0);
    write_varint(&mut short_sum, 99);
    let error = decode(&short_sum).unwrap_err();
    assert!(
        matches!(&error, GrayCodecError::BadTable { context: 0, why } if why.contains("sum to 100")),
        "{error}"
    );
    // Every table empty: the first pixel has nothing to be decoded with.
    let mut empty = MAGIC.to_vec();
    empty.extend_from_slice(&2u32.to_le_bytes());
    empty.extend_from_slice(&2u32.to_le_bytes());
    empty.extend(std::iter::repeat_n(0, CONTEXTS));
    for _ in 0..4 {
        empty.extend_from_slice(&RANS_LOW.to_le_bytes());
    }
    assert_eq!(decode(&empty), Err(GrayCodecError::EmptyContext(0)));
}

#[test]
fn residual_symbols_cover_every_byte_once() {
    let symbols: std::collections::BTreeSet<u8> = (0..=255u8).map(zigzag).collect();
    assert_eq!(symbols.len(), 256);
    for residual in 0..=255u8 {
        assert_eq!(unzigzag(zigzag(residual)), residual);
    }
    // Small residuals of either sign get the small symbols.
    assert_eq!([0, 255, 1, 254].map(zigzag), [0, 1, 2, 3]);
}
