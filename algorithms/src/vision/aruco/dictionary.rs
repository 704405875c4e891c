//! ArUco dictionaries: the marker codes a detector accepts, their four rotations and
//! Hamming-distance identification with error correction.
//!
//! A code packs a marker's inner `n`×`n` bits (the black border excluded) into a `u64`,
//! row-major with bit `row * n + col` for the cell at (row, col), row 0 at the top and column 0
//! at the left of the upright marker, and **black = 1**. This is the packing of the
//! `calib-targets-aruco` crate, which embeds OpenCV's predefined dictionaries (OpenCV's own
//! `bytesList` is the same grid read most-significant-bit first with white = 1).

use thiserror::Error;

/// Name of OpenCV's `DICT_4X4_50`.
pub const DICT_4X4_50: &str = "DICT_4X4_50";
/// Name of OpenCV's `DICT_ARUCO_ORIGINAL` (the original ArUco library's 5×5, 1024-id codes).
pub const DICT_ARUCO_ORIGINAL: &str = "DICT_ARUCO_ORIGINAL";

/// The original ArUco library's row words, indexed by the two id bits a row carries; written
/// as the library draws them, most significant bit = leftmost cell, 1 = white. It is a
/// Hamming-style code: bits 2 and 4 (counting from 1 at the left) carry the data, bits 1, 3
/// and 5 are parity, and any two words differ in at least 3 bits.
const ARUCO_ORIGINAL_ROW_WORDS: [u64; 4] = [0b10000, 0b10111, 0b01001, 0b01110];

/// A dictionary that cannot be built as given.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum DictionaryError {
    #[error("unknown ArUco dictionary {name:?}; known: {DICT_4X4_50}, {DICT_ARUCO_ORIGINAL}")]
    Unknown { name: String },
    #[error("marker size {marker_size_bits} bits is out of range (2 to 8 inner bits per side)")]
    MarkerSize { marker_size_bits: usize },
    #[error("dictionary {name:?} has no codes")]
    Empty { name: String },
    #[error("code {id} ({code:#x}) uses bits beyond the {bit_count} of a marker")]
    CodeOutOfRange {
        id: usize,
        code: u64,
        bit_count: usize,
    },
}

/// A dictionary's answer for a sampled code.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CodeMatch {
    /// Marker id: the index of the code in the dictionary.
    pub id: usize,
    /// Bits that differ between the sampled code and the marker's code, after rotation.
    pub hamming_distance: u32,
    /// Counter-clockwise quarter turns that take the upright marker's code to the sampled one
    /// (`sampled == rotate_code(code, n, quarter_turns)`).
    pub quarter_turns: u8,
}

/// A set of square markers: `marker_size_bits`² inner bits each, inside a one-cell black border.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Dictionary {
    name: String,
    marker_size_bits: usize,
    max_correction_bits: u32,
    /// `rotations[id][k]` = the code of `id` turned `k` quarter turns counter-clockwise.
    rotations: Vec<[u64; 4]>,
}

impl Dictionary {
    /// A dictionary from codes packed as described in the module documentation.
    pub fn new(
        name: impl Into<String>,
        marker_size_bits: usize,
        max_correction_bits: u32,
        codes: &[u64],
    ) -> Result<Self, DictionaryError> {
        let name = name.into();
        if !(2..=8).contains(&marker_size_bits) {
            return Err(DictionaryError::MarkerSize { marker_size_bits });
        }
        if codes.is_empty() {
            return Err(DictionaryError::Empty { name });
        }
        let bit_count = marker_size_bits * marker_size_bits;
        let mask = bit_mask(bit_count);
        let mut rotations = Vec::with_capacity(codes.len());
        for (id, &code) in codes.iter().enumerate() {
            if code & !mask != 0 {
                return Err(DictionaryError::CodeOutOfRange {
                    id,
                    code,
                    bit_count,
                });
            }
            let mut turned = [code; 4];
            for k in 1..4 {
                turned[k] = rotate_code(turned[k - 1], marker_size_bits, 1);
            }
            rotations.push(turned);
        }
        Ok(Self {
            name,
            marker_size_bits,
            max_correction_bits,
            rotations,
        })
    }

    /// A predefined dictionary by its OpenCV name (`DICT_4X4_50`, `DICT_ARUCO_ORIGINAL`).
    pub fn by_name(name: &str) -> Result<Self, DictionaryError> {
        match name {
            DICT_4X4_50 => Ok(Self::dict_4x4_50()),
            DICT_ARUCO_ORIGINAL => Ok(Self::aruco_original()),
            _ => Err(DictionaryError::Unknown {
                name: name.to_string(),
            }),
        }
    }

    /// OpenCV's `DICT_4X4_50`: 50 ids of 4×4 bits, corrects 1 bit.
    pub fn dict_4x4_50() -> Self {
        // Embedded in calib-targets-aruco at its build time: present by construction, and its
        // codes fit 4×4 bits, so neither step depends on anything a caller passes.
        let opencv = calib_targets_aruco::builtins::builtin_dictionary(DICT_4X4_50)
            .expect("calib-targets-aruco embeds DICT_4X4_50");
        Self::new(
            DICT_4X4_50,
            opencv.marker_size(),
            u32::from(opencv.max_correction_bits()),
            opencv.codes(),
        )
        .expect("OpenCV's DICT_4X4_50 codes are 16-bit")
    }

    /// The original ArUco library's dictionary (OpenCV's `DICT_ARUCO_ORIGINAL`): 1024 ids of
    /// 5×5 bits. Row `r` (0 = top) carries id bits `2(4 − r) + 1` and `2(4 − r)` (most
    /// significant pair first) as one of four 5-bit words {10000, 10111, 01001, 01110}
    /// (1 = white, leftmost cell first), exactly as the original library's
    /// `createMarkerImage` draws them. OpenCV corrects no bits with it (several ids are
    /// rotations of one another, so it has no margin to spend), and neither does this.
    pub fn aruco_original() -> Self {
        let codes: Vec<u64> = (0..1024u64).map(aruco_original_code).collect();
        Self {
            name: DICT_ARUCO_ORIGINAL.to_string(),
            marker_size_bits: 5,
            max_correction_bits: 0,
            rotations: codes
                .iter()
                .map(|&code| {
                    [
                        code,
                        rotate_code(code, 5, 1),
                        rotate_code(code, 5, 2),
                        rotate_code(code, 5, 3),
                    ]
                })
                .collect(),
        }
    }

    pub fn name(&self) -> &str {
        &self.name
    }

    /// Inner bits per side (4 for DICT_4X4_50).
    pub fn marker_size_bits(&self) -> usize {
        self.marker_size_bits
    }

    /// Bit errors a sampled code may have and still be read as a marker.
    pub fn max_correction_bits(&self) -> u32 {
        self.max_correction_bits
    }

    /// Number of ids.
    pub fn len(&self) -> usize {
        self.rotations.len()
    }

    pub fn is_empty(&self) -> bool {
        self.rotations.is_empty()
    }

    /// The upright code of `id`.
    pub fn code(&self, id: usize) -> Option<u64> {
        self.rotations.get(id).map(|turned| turned[0])
    }

    /// Whether `id` looks the same after a half or quarter turn: it is still read, but which
    /// corner is its top-left cannot be told (DICT_ARUCO_ORIGINAL's id 1023, all rows 01110,
    /// is the only such marker of the two predefined dictionaries). `None` for an unknown id.
    pub fn is_rotation_symmetric(&self, id: usize) -> Option<bool> {
        let turned = self.rotations.get(id)?;
        Some(turned[1..].contains(&turned[0]))
    }

    /// The inner bits of the upright marker `id`, row-major from the top-left, `true` = white:
    /// OpenCV's convention and what [`crate::vision::render::Texture::aruco`] draws.
    pub fn marker_bits(&self, id: usize) -> Option<Vec<bool>> {
        let code = self.code(id)?;
        let bit_count = self.marker_size_bits * self.marker_size_bits;
        Some((0..bit_count).map(|i| (code >> i) & 1 == 0).collect())
    }

    /// The closest marker to a sampled code over all ids and four rotations, if it is within
    /// `max_correction_bits` bits. Ties go to the lowest id, then the fewest turns.
    pub fn identify(&self, sampled: u64, max_correction_bits: u32) -> Option<CodeMatch> {
        let mut best: Option<CodeMatch> = None;
        for (id, turned) in self.rotations.iter().enumerate() {
            for (k, &code) in turned.iter().enumerate() {
                let distance = (code ^ sampled).count_ones();
                if distance <= max_correction_bits
                    && best.is_none_or(|b| distance < b.hamming_distance)
                {
                    best = Some(CodeMatch {
                        id,
                        hamming_distance: distance,
                        quarter_turns: k as u8,
                    });
                    if distance == 0 {
                        return best;
                    }
                }
            }
        }
        best
    }

    /// The smallest Hamming distance between two different (id, rotation) codes, and between a
    /// code and its own other rotations: the dictionary corrects up to `(d − 1) / 2` bits.
    pub fn min_distance_bits(&self) -> u32 {
        let mut min = u32::MAX;
        for (i, a) in self.rotations.iter().enumerate() {
            for k in 1..4 {
                min = min.min((a[0] ^ a[k]).count_ones());
            }
            for b in &self.rotations[i + 1..] {
                for &code in b {
                    min = min.min((a[0] ^ code).count_ones());
                }
            }
        }
        min
    }
}

/// The original ArUco code of `id` (0..1024), packed black = 1, bit `row * 5 + col`.
fn aruco_original_code(id: u64) -> u64 {
    let mut code = 0;
    for row in 0..5 {
        let word = ARUCO_ORIGINAL_ROW_WORDS[((id >> (2 * (4 - row))) & 3) as usize];
        for col in 0..5 {
            let white = (word >> (4 - col)) & 1 == 1;
            if !white {
                code |= 1 << (row * 5 + col);
            }
        }
    }
    code
}

fn bit_mask(bit_count: usize) -> u64 {
    if bit_count >= 64 {
        u64::MAX
    } else {
        (1 << bit_count) - 1
    }
}

/// `code` (an `n`×`n` grid) turned `quarter_turns` times counter-clockwise as seen on screen:
/// the cell at (row, col) of the result is the cell at (col, n − 1 − row) of the input.
pub fn rotate_code(code: u64, n: usize, quarter_turns: u8) -> u64 {
    let mut out = code;
    for _ in 0..quarter_turns % 4 {
        let mut turned = 0;
        for row in 0..n {
            for col in 0..n {
                let src = col * n + (n - 1 - row);
                turned |= ((out >> src) & 1) << (row * n + col);
            }
        }
        out = turned;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A grid written as rows of '#' (black) and '.' (white), packed black = 1.
    fn pack(rows: &[&str]) -> u64 {
        let n = rows.len();
        let mut code = 0;
        for (row, line) in rows.iter().enumerate() {
            for (col, ch) in line.chars().enumerate() {
                if ch == '#' {
                    code |= 1 << (row * n + col);
                }
            }
        }
        code
    }

    /// OpenCV's `bytesList` for one rotation: the grid read row-major, most significant bit
    /// first, 1 = white, in bytes.
    fn opencv_bytes(code: u64, n: usize) -> Vec<u8> {
        let bits: Vec<bool> = (0..n * n).map(|i| (code >> i) & 1 == 0).collect();
        bits.chunks(8)
            .map(|chunk| {
                chunk
                    .iter()
                    .enumerate()
                    .fold(0u8, |b, (i, &white)| b | (u8::from(white) << (7 - i)))
            })
            .collect()
    }

    #[test]
    fn dict_4x4_50_matches_opencv() {
        let dict = Dictionary::dict_4x4_50();
        assert_eq!(dict.len(), 50);
        assert_eq!(dict.marker_size_bits(), 4);
        assert_eq!(dict.max_correction_bits(), 1);
        // OpenCV's predefined_dictionaries.hpp opens DICT_4X4_50_BYTES with
        // { { 181, 50 }, { 235, 72 }, ... }: id 0 upright, then turned a quarter.
        let id0 = dict.code(0).unwrap();
        assert_eq!(opencv_bytes(id0, 4), vec![181, 50]);
        assert_eq!(opencv_bytes(rotate_code(id0, 4, 1), 4), vec![235, 72]);
        // The same marker as OpenCV draws it (generateImageMarker), inner bits only.
        assert_eq!(id0, pack(&[".#..", "#.#.", "##..", "##.#"]));
        // Its codes are at least 3 bits apart over all rotations, so 1 bit is correctable.
        assert!(dict.min_distance_bits() >= 3);
    }

    #[test]
    fn aruco_original_follows_the_libraries_construction() {
        let dict = Dictionary::aruco_original();
        assert_eq!(dict.len(), 1024);
        // Id 0: every row is word 10000 (white, then four black cells).
        assert_eq!(dict.code(0).unwrap(), pack(&[".####"; 5]));
        // Id 1 changes only the last row (least significant pair) to word 10111.
        assert_eq!(
            dict.code(1).unwrap(),
            pack(&[".####", ".####", ".####", ".####", ".#..."])
        );
        // Id 1023: all pairs 11 -> word 01110 in every row.
        assert_eq!(dict.code(1023).unwrap(), pack(&["#...#"; 5]));
        // Id 0b10_01_00_11_10 = 590: rows use words 2, 1, 0, 3, 2.
        assert_eq!(
            dict.code(0b10_01_00_11_10).unwrap(),
            pack(&["#.##.", ".#...", ".####", "#...#", "#.##."])
        );
    }

    #[test]
    fn only_aruco_original_1023_is_symmetric() {
        let original = Dictionary::aruco_original();
        let symmetric: Vec<usize> = (0..original.len())
            .filter(|&id| original.is_rotation_symmetric(id) == Some(true))
            .collect();
        assert_eq!(symmetric, vec![1023]);
        let opencv = Dictionary::dict_4x4_50();
        assert!((0..50).all(|id| opencv.is_rotation_symmetric(id) == Some(false)));
        assert_eq!(opencv.is_rotation_symmetric(50), None);
        // No two ids of the original dictionary are rotations of each other: each id is
        // told apart from every other, if with no bit to spare.
        for (i, a) in original.rotations.iter().enumerate() {
            for b in &original.rotations[i + 1..] {
                assert!(b.iter().all(|&code| code != a[0]));
            }
        }
    }

    #[test]
    fn aruco_original_equals_opencvs_embedded_table() {
        // An independent source: the table OpenCV ships, as embedded by calib-targets-aruco.
        let opencv = calib_targets_aruco::builtins::builtin_dictionary(DICT_ARUCO_ORIGINAL)
            .expect("embedded");
        let ours = Dictionary::aruco_original();
        assert_eq!(opencv.codes().len(), ours.len());
        for (id, &code) in opencv.codes().iter().enumerate() {
            assert_eq!(ours.code(id), Some(code), "id {id}");
        }
        assert_eq!(
            u32::from(opencv.max_correction_bits()),
            ours.max_correction_bits()
        );
    }

    #[test]
    fn rotation_turns_counter_clockwise_and_cycles() {
        let upright = pack(&["##..", "....", "....", "...."]);
        // Turned counter-clockwise, the top row becomes the left column, read bottom-up.
        let turned = pack(&["....", "....", "#...", "#..."]);
        assert_eq!(rotate_code(upright, 4, 1), turned);
        for code in [0xb352u64, 0x1ef7bde] {
            let n = if code > 0xffff { 5 } else { 4 };
            assert_eq!(rotate_code(code, n, 4), code);
            assert_eq!(rotate_code(rotate_code(code, n, 1), n, 3), code);
        }
    }

    #[test]
    fn identify_corrects_up_to_the_limit() {
        let dict = Dictionary::dict_4x4_50();
        for id in 0..dict.len() {
            for k in 0..4u8 {
                let code = rotate_code(dict.code(id).unwrap(), 4, k);
                let found = dict.identify(code, 1).unwrap();
                assert_eq!(
                    (found.id, found.quarter_turns, found.hamming_distance),
                    (id, k, 0)
                );
                for bit in 0..16 {
                    let found = dict.identify(code ^ (1 << bit), 1).unwrap();
                    assert_eq!((found.id, found.quarter_turns), (id, k));
                    assert_eq!(found.hamming_distance, 1);
                }
            }
        }
        // Three flipped bits are beyond correction: the marker is never read as itself.
        let code = dict.code(7).unwrap() ^ 0b111;
        assert!(dict.identify(code, 1).is_none_or(|m| m.id != 7));
        assert_eq!(dict.identify(0, 1), None);
    }

    #[test]
    fn bad_dictionaries_are_named_errors() {
        assert!(matches!(
            Dictionary::by_name("DICT_6X6_250"),
            Err(DictionaryError::Unknown { .. })
        ));
        assert!(matches!(
            Dictionary::new("x", 9, 0, &[1]),
            Err(DictionaryError::MarkerSize { .. })
        ));
        assert!(matches!(
            Dictionary::new("x", 4, 0, &[]),
            Err(DictionaryError::Empty { .. })
        ));
        assert!(matches!(
            Dictionary::new("x", 4, 0, &[1 << 16]),
            Err(DictionaryError::CodeOutOfRange { id: 0, .. })
        ));
        assert_eq!(
            Dictionary::by_name(DICT_4X4_50).unwrap(),
            Dictionary::dict_4x4_50()
        );
    }

    #[test]
    fn marker_bits_are_white_true_row_major() {
        let dict = Dictionary::dict_4x4_50();
        let bits = dict.marker_bits(0).unwrap();
        // Id 0 is ".#.. / #.#. / ##.. / ##.#" ('#' black).
        let expected: Vec<bool> = ".#..#.#.##..##.#".chars().map(|c| c == '.').collect();
        assert_eq!(bits, expected);
        assert_eq!(dict.marker_bits(50), None);
    }
}
