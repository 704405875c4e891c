//! The baked field under a camera: the ground points of one 640×480 frame from 7.5 m (1.36 cm
//! apart, as the reference mission's camera sees them) sampled row by row with
//! `Texture::sample_many`, near the origin and 1 km out (where the reference mission's tractor
//! is after 11 minutes, far outside the baked square, so every point wraps), against the
//! one-point path (`Texture::sample`, each point wrapped on its own) 1 km out, measured in the
//! same run: the baseline, and what each ground pixel out there cost before a row shared its wrap.
//!
//! `cargo bench -p sim --bench field`

use sim::scene::{baked_texture, FIELD_BAKED_HALF_EXTENT_M, FIELD_TEXEL_M};
use std::hint::black_box;
use std::time::Instant;

const WIDTH: usize = 640;
const HEIGHT: usize = 480;
const SPACING_M: f64 = 0.0136;
const REPEATS: usize = 20;

/// A frame's ground points with its rows at `yaw_rad` from east (a level camera's rows run
/// along its right axis, wherever the vehicle heads).
fn frame_points(north_m: f64, east_m: f64, yaw_rad: f64) -> Vec<[f64; 2]> {
    let (sin, cos) = yaw_rad.sin_cos();
    (0..WIDTH * HEIGHT)
        .map(|k| {
            let (row, col) = ((k / WIDTH) as f64, (k % WIDTH) as f64);
            [
                north_m + (row * cos + col * sin) * SPACING_M,
                east_m + (col * cos - row * sin) * SPACING_M,
            ]
        })
        .collect()
}

/// The fastest of `REPEATS` frames, milliseconds.
fn best_ms(mut frame: impl FnMut()) -> f64 {
    frame(); // bakes the tiles the frame needs
    (0..REPEATS)
        .map(|_| {
            let started = Instant::now();
            frame();
            started.elapsed().as_secs_f64() * 1000.0
        })
        .fold(f64::INFINITY, f64::min)
}

fn main() {
    let field = baked_texture(
        algorithms::vision::render::Texture::field(7),
        FIELD_TEXEL_M,
        FIELD_BAKED_HALF_EXTENT_M,
    );
    let near = frame_points(10.0, -4.0, 0.0);
    let far = frame_points(1000.0, -4.0, 0.0);
    let turned = frame_points(1000.0, -4.0, 0.65);
    let mut row_values = vec![0f32; WIDTH];
    let mut many = |points: &[[f64; 2]]| {
        best_ms(|| {
            for row in points.chunks(WIDTH) {
                field.sample_many(row, &mut row_values);
                black_box(&row_values);
            }
        })
    };
    let near_ms = many(&near);
    let far_ms = many(&far);
    let turned_ms = many(&turned);
    let one_by_one_ms = best_ms(|| {
        for &[north_m, east_m] in &far {
            black_box(field.sample(north_m, east_m));
        }
    });
    println!("one frame of ground points, fastest of {REPEATS}:");
    println!("  sample_many, near the origin            : {near_ms:6.2} ms");
    println!("  sample_many, 1 km out                   : {far_ms:6.2} ms");
    println!("  sample_many, 1 km out, rows turned 37°  : {turned_ms:6.2} ms");
    println!("  one point at a time, 1 km out (baseline): {one_by_one_ms:6.2} ms");
    println!(
        "1 km out, a row's shared wrap samples the frame {:.2}× as fast as the one-point path",
        one_by_one_ms / far_ms
    );
}
