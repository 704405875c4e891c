//! Feature points for motion compensation (seed 000, §2.2.2): FAST corners with non-maximum
//! suppression, steered BRIEF descriptors on a smoothed image, and brute-force Hamming matching
//! with a ratio test and a cross check.
//!
//! The seed matches SIFT features (SIFT-GPU). Between consecutive frames of a downward camera the
//! scale barely changes, so FAST + BRIEF (as in ORB, without its pyramid) serves at a fraction
//! of the cost; the descriptor is steered by the intensity-centroid orientation so that the
//! vehicle's yaw between frames does not break the matching. Feed it rectified (pinhole) frames,
//! as the seed does: a homography only holds without lens distortion.

use super::image::ImageView;
use super::render::SplitMix64;

/// A corner, pixel coordinates (integer values are pixel centres).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Keypoint {
    pub x_px: f64,
    pub y_px: f64,
    /// FAST score: how far the arc's pixels exceed the threshold, summed.
    pub score: f32,
    /// Orientation by the intensity centroid (set by [`BriefExtractor::describe`]), radians from
    /// the x axis towards y.
    pub angle_rad: f64,
}

/// FAST-9 settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FastConfig {
    /// Intensity difference (0–255) that makes a circle pixel brighter or darker than the centre.
    pub threshold: u8,
    /// Keep only local maxima of the score in 3×3.
    pub nonmax_suppression: bool,
    /// Keep at most this many, the strongest spread over a grid of cells.
    pub max_keypoints: usize,
    /// Cells per image side for spreading the kept keypoints (1: strongest overall).
    pub grid_cells: usize,
    /// Pixels to skip at each image edge (at least 3, the circle's radius).
    pub border_px: usize,
}

impl Default for FastConfig {
    fn default() -> Self {
        Self {
            threshold: 20,
            nonmax_suppression: true,
            max_keypoints: 800,
            grid_cells: 4,
            border_px: BRIEF_BORDER_PX,
        }
    }
}

/// The 16 pixels of the Bresenham circle of radius 3, clockwise from the top.
const CIRCLE: [(i32, i32); 16] = [
    (0, -3),
    (1, -3),
    (2, -2),
    (3, -1),
    (3, 0),
    (3, 1),
    (2, 2),
    (1, 3),
    (0, 3),
    (-1, 3),
    (-2, 2),
    (-3, 1),
    (-3, 0),
    (-3, -1),
    (-2, -2),
    (-1, -3),
];

/// Contiguous circle pixels that make a corner (FAST-9).
const ARC: u32 = 9;

/// Whether a 16-bit circular mask holds a run of at least [`ARC`] ones.
fn has_arc(mask: u32) -> bool {
    let mut run = mask | (mask << 16);
    for _ in 1..ARC {
        run &= run >> 1;
    }
    run != 0
}

/// The FAST score of pixel (x, y) if it is a corner: `max(Σ_bright (d − t), Σ_dark (−d − t))`
/// over the circle's differences d from the centre (Rosten & Drummond's V).
fn corner_score(image: &ImageView<'_>, x: usize, y: usize, threshold: i32) -> Option<f32> {
    let centre = image.get(x, y) as i32;
    let at = |k: usize| {
        let (dx, dy) = CIRCLE[k];
        image.get((x as i32 + dx) as usize, (y as i32 + dy) as usize) as i32 - centre
    };
    // A 9-arc covers at least two of the four compass pixels: reject most pixels with four reads.
    let compass = [at(0), at(4), at(8), at(12)];
    let bright = compass.iter().filter(|&&d| d > threshold).count();
    let dark = compass.iter().filter(|&&d| d < -threshold).count();
    if bright < 2 && dark < 2 {
        return None;
    }
    let (mut bright_mask, mut dark_mask) = (0u32, 0u32);
    let (mut bright_sum, mut dark_sum) = (0i32, 0i32);
    for k in 0..16 {
        let d = at(k);
        if d > threshold {
            bright_mask |= 1 << k;
            bright_sum += d - threshold;
        } else if d < -threshold {
            dark_mask |= 1 << k;
            dark_sum += -d - threshold;
        }
    }
    match (has_arc(bright_mask), has_arc(dark_mask)) {
        (false, false) => None,
        (true, false) => Some(bright_sum as f32),
        (false, true) => Some(dark_sum as f32),
        (true, true) => Some(bright_sum.max(dark_sum) as f32),
    }
}

/// FAST-9 corners of `image`, strongest first within each grid cell; see [`FastConfig`].
pub fn detect_fast(image: &ImageView<'_>, config: &FastConfig) -> Vec<Keypoint> {
    let (width, height) = (image.width(), image.height());
    let border = config.border_px.max(3);
    if width <= 2 * border || height <= 2 * border {
        return Vec::new();
    }
    let threshold = config.threshold as i32;
    let mut scores = vec![0f32; width * height];
    for y in border..height - border {
        for x in border..width - border {
            if let Some(s) = corner_score(image, x, y, threshold) {
                // A corner's score is positive: every arc pixel exceeds the threshold.
                scores[y * width + x] = s.max(f32::MIN_POSITIVE);
            }
        }
    }
    let mut corners = Vec::new();
    for y in border..height - border {
        for x in border..width - border {
            let s = scores[y * width + x];
            if s <= 0.0 {
                continue;
            }
            if config.nonmax_suppression && !is_local_max(&scores, width, x, y) {
                continue;
            }
            corners.push(Keypoint {
                x_px: x as f64,
                y_px: y as f64,
                score: s,
                angle_rad: 0.0,
            });
        }
    }
    keep_strongest(corners, config, width, height)
}

/// Strictly above the neighbours before it in raster order, at least equal to those after it:
/// exactly one of a plateau of equal scores survives.
fn is_local_max(scores: &[f32], width: usize, x: usize, y: usize) -> bool {
    let s = scores[y * width + x];
    for dy in -1i32..=1 {
        for dx in -1i32..=1 {
            if dx == 0 && dy == 0 {
                continue;
            }
            let n = scores[(y as i32 + dy) as usize * width + (x as i32 + dx) as usize];
            let before = dy < 0 || (dy == 0 && dx < 0);
            if n > s || (before && n == s) {
                return false;
            }
        }
    }
    true
}

/// At most `max_keypoints`, shared evenly among `grid_cells²` cells, the strongest in each (so
/// the homography sees the whole image, not one textured corner of it).
fn keep_strongest(
    mut corners: Vec<Keypoint>,
    config: &FastConfig,
    width: usize,
    height: usize,
) -> Vec<Keypoint> {
    corners.sort_by(|a, b| b.score.total_cmp(&a.score));
    if corners.len() <= config.max_keypoints {
        return corners;
    }
    let cells = config.grid_cells.max(1);
    let per_cell = config.max_keypoints.div_ceil(cells * cells);
    let mut counts = vec![0usize; cells * cells];
    let mut kept = Vec::with_capacity(config.max_keypoints);
    let mut rest = Vec::new();
    for c in corners {
        let cx = (c.x_px as usize * cells / width).min(cells - 1);
        let cy = (c.y_px as usize * cells / height).min(cells - 1);
        let n = &mut counts[cy * cells + cx];
        if *n < per_cell && kept.len() < config.max_keypoints {
            *n += 1;
            kept.push(c);
        } else {
            rest.push(c);
        }
    }
    // Cells with few corners leave room: fill it with the strongest of the rest.
    let room = config.max_keypoints - kept.len();
    kept.extend(rest.into_iter().take(room));
    kept
}

/// A 256-bit binary descriptor.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Descriptor(pub [u64; 4]);

impl Descriptor {
    /// Number of differing bits.
    pub fn hamming(&self, other: &Self) -> u32 {
        self.0
            .iter()
            .zip(&other.0)
            .map(|(a, b)| (a ^ b).count_ones())
            .sum()
    }
}

/// Radius of the test pattern; rotated, it stays within this.
const PATTERN_RADIUS_PX: f64 = 13.0;
/// Radius of the patch whose intensity centroid orients the descriptor.
const ORIENTATION_RADIUS_PX: i32 = 15;
/// Smoothing before the binary tests (BRIEF's noise robustness).
const BLUR_SIGMA_PX: f64 = 2.0;
const BLUR_RADIUS_PX: usize = 5;
/// Keypoints nearer the edge than this cannot be described.
pub const BRIEF_BORDER_PX: usize = 16;

/// Steered BRIEF: 256 intensity comparisons between point pairs drawn from an isotropic
/// Gaussian (σ = 31/5 px, clipped to a 13 px radius) with a seeded generator, rotated by the
/// keypoint's orientation, on a Gaussian-smoothed image.
#[derive(Debug, Clone)]
pub struct BriefExtractor {
    pattern: Vec<[f64; 4]>,
    steered: bool,
}

impl BriefExtractor {
    /// The pattern drawn from `seed`; two extractors compare only with the same seed.
    pub fn new(seed: u64, steered: bool) -> Self {
        let mut rng = SplitMix64::new(seed);
        let sigma = 31.0 / 5.0;
        let mut point = || loop {
            let (x, y) = (rng.next_gaussian() * sigma, rng.next_gaussian() * sigma);
            if x.hypot(y) <= PATTERN_RADIUS_PX {
                return (x, y);
            }
        };
        let pattern = (0..256)
            .map(|_| {
                let (a, b) = (point(), point());
                [a.0, a.1, b.0, b.1]
            })
            .collect();
        Self { pattern, steered }
    }

    /// Descriptors of the keypoints far enough from the edge, each with its keypoint (its
    /// orientation filled in when steered).
    pub fn describe(
        &self,
        image: &ImageView<'_>,
        keypoints: &[Keypoint],
    ) -> Vec<(Keypoint, Descriptor)> {
        let (width, height) = (image.width(), image.height());
        let smooth = gaussian_smooth(image);
        let at = |x: i32, y: i32| smooth[y as usize * width + x as usize];
        let mut out = Vec::with_capacity(keypoints.len());
        for kp in keypoints {
            let (x, y) = (kp.x_px.round() as i64, kp.y_px.round() as i64);
            let b = BRIEF_BORDER_PX as i64;
            if x < b || y < b || x >= width as i64 - b || y >= height as i64 - b {
                continue;
            }
            let (x, y) = (x as i32, y as i32);
            let angle_rad = if self.steered {
                intensity_centroid_angle(&at, x, y)
            } else {
                0.0
            };
            let (sin, cos) = angle_rad.sin_cos();
            let rotate = |px: f64, py: f64| {
                (
                    x + (cos * px - sin * py).round() as i32,
                    y + (sin * px + cos * py).round() as i32,
                )
            };
            let mut bits = [0u64; 4];
            for (i, p) in self.pattern.iter().enumerate() {
                let (ax, ay) = rotate(p[0], p[1]);
                let (bx, by) = rotate(p[2], p[3]);
                if at(ax, ay) < at(bx, by) {
                    bits[i / 64] |= 1 << (i % 64);
                }
            }
            out.push((Keypoint { angle_rad, ..*kp }, Descriptor(bits)));
        }
        out
    }
}

/// Angle of the vector from (x, y) to the intensity centroid of the disc around it.
fn intensity_centroid_angle(at: &impl Fn(i32, i32) -> f32, x: i32, y: i32) -> f64 {
    let r = ORIENTATION_RADIUS_PX;
    let (mut m10, mut m01) = (0f64, 0f64);
    for dy in -r..=r {
        for dx in -r..=r {
            if dx * dx + dy * dy <= r * r {
                let i = at(x + dx, y + dy) as f64;
                m10 += dx as f64 * i;
                m01 += dy as f64 * i;
            }
        }
    }
    if m10 == 0.0 && m01 == 0.0 {
        0.0
    } else {
        m01.atan2(m10)
    }
}

/// Separable Gaussian blur with clamped edges, as f32.
fn gaussian_smooth(image: &ImageView<'_>) -> Vec<f32> {
    let (width, height) = (image.width(), image.height());
    let r = BLUR_RADIUS_PX as i64;
    let taps: Vec<f32> = (-r..=r)
        .map(|i| (-(i * i) as f64 / (2.0 * BLUR_SIGMA_PX * BLUR_SIGMA_PX)).exp() as f32)
        .collect();
    let total: f32 = taps.iter().sum();
    let taps: Vec<f32> = taps.iter().map(|t| t / total).collect();
    let clamp = |v: i64, len: usize| v.clamp(0, len as i64 - 1) as usize;
    let mut tmp = vec![0f32; width * height];
    for y in 0..height {
        let row = image.row(y);
        for x in 0..width {
            tmp[y * width + x] = taps
                .iter()
                .enumerate()
                .map(|(i, t)| t * row[clamp(x as i64 + i as i64 - r, width)] as f32)
                .sum();
        }
    }
    let mut out = vec![0f32; width * height];
    for y in 0..height {
        for x in 0..width {
            out[y * width + x] = taps
                .iter()
                .enumerate()
                .map(|(i, t)| t * tmp[clamp(y as i64 + i as i64 - r, height) * width + x])
                .sum();
        }
    }
    out
}

/// How to match descriptors.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MatchConfig {
    /// Matches with more differing bits than this are dropped (of 256).
    pub max_distance: u32,
    /// Lowe's ratio test: keep a match only if its distance is below `ratio` × the second best.
    pub ratio: Option<f64>,
    /// Keep a match only if each descriptor is the other's best.
    pub cross_check: bool,
}

impl Default for MatchConfig {
    fn default() -> Self {
        Self {
            max_distance: 64,
            ratio: Some(0.8),
            cross_check: true,
        }
    }
}

/// `query[query_index]` matched with `train[train_index]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DescriptorMatch {
    pub query_index: usize,
    pub train_index: usize,
    pub distance: u32,
}

/// The best and second-best distances from `d` into `set`, with the best's index.
fn two_nearest(d: &Descriptor, set: &[Descriptor]) -> Option<(usize, u32, u32)> {
    let mut best: Option<(usize, u32)> = None;
    let mut second = u32::MAX;
    for (j, t) in set.iter().enumerate() {
        let dist = d.hamming(t);
        match best {
            Some((_, b)) if dist >= b => second = second.min(dist),
            _ => {
                if let Some((_, b)) = best {
                    second = b;
                }
                best = Some((j, dist));
            }
        }
    }
    best.map(|(j, b)| (j, b, second))
}

/// Brute-force Hamming matching of every query descriptor against all train descriptors; see
/// [`MatchConfig`]. Sorted by query index.
pub fn match_descriptors(
    query: &[Descriptor],
    train: &[Descriptor],
    config: &MatchConfig,
) -> Vec<DescriptorMatch> {
    let reverse_best: Vec<Option<usize>> = if config.cross_check {
        train
            .iter()
            .map(|t| two_nearest(t, query).map(|(i, _, _)| i))
            .collect()
    } else {
        Vec::new()
    };
    let mut matches = Vec::new();
    for (i, q) in query.iter().enumerate() {
        let Some((j, best, second)) = two_nearest(q, train) else {
            continue;
        };
        if best > config.max_distance {
            continue;
        }
        if let Some(ratio) = config.ratio {
            if second != u32::MAX && best as f64 >= ratio * second as f64 {
                continue;
            }
        }
        if config.cross_check && reverse_best[j] != Some(i) {
            continue;
        }
        matches.push(DescriptorMatch {
            query_index: i,
            train_index: j,
            distance: best,
        });
    }
    matches
}

/// Everything the frame-to-frame matcher needs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FeatureConfig {
    pub fast: FastConfig,
    pub matching: MatchConfig,
    /// Seed of the BRIEF pattern.
    pub brief_seed: u64,
    /// Steer descriptors by orientation (robust to yaw between frames).
    pub steered: bool,
}

impl Default for FeatureConfig {
    fn default() -> Self {
        Self {
            fast: FastConfig::default(),
            matching: MatchConfig::default(),
            brief_seed: 0x5eed_0000,
            steered: true,
        }
    }
}

/// A frame's described keypoints: keep the previous frame's to match the next.
#[derive(Debug, Clone, Default)]
pub struct FrameFeatures {
    pub keypoints: Vec<Keypoint>,
    pub descriptors: Vec<Descriptor>,
}

/// A point seen in both frames, pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Correspondence {
    pub previous_px: [f64; 2],
    pub current_px: [f64; 2],
    pub distance: u32,
}

/// Detects, describes and matches features between frames.
#[derive(Debug, Clone)]
pub struct FeatureMatcher {
    config: FeatureConfig,
    brief: BriefExtractor,
}

impl FeatureMatcher {
    pub fn new(config: FeatureConfig) -> Self {
        Self {
            brief: BriefExtractor::new(config.brief_seed, config.steered),
            config,
        }
    }

    pub fn config(&self) -> &FeatureConfig {
        &self.config
    }

    /// FAST corners of the frame with their descriptors.
    pub fn features(&self, image: &ImageView<'_>) -> FrameFeatures {
        let corners = detect_fast(image, &self.config.fast);
        let (keypoints, descriptors) = self.brief.describe(image, &corners).into_iter().unzip();
        FrameFeatures {
            keypoints,
            descriptors,
        }
    }

    /// Matched points from the previous frame to the current one.
    pub fn correspondences(
        &self,
        previous: &FrameFeatures,
        current: &FrameFeatures,
    ) -> Vec<Correspondence> {
        match_descriptors(
            &previous.descriptors,
            &current.descriptors,
            &self.config.matching,
        )
        .into_iter()
        .map(|m| {
            let (p, c) = (
                previous.keypoints[m.query_index],
                current.keypoints[m.train_index],
            );
            Correspondence {
                previous_px: [p.x_px, p.y_px],
                current_px: [c.x_px, c.y_px],
                distance: m.distance,
            }
        })
        .collect()
    }
}

#[cfg(test)]
mod tests;
