//! The compact codec's entropy coding: each context's frequency table as the bitstream holds
//! it, the decoder's lookup, the encoder's rANS constants, and the byte reading that names
//! where a frame ends early.

use super::{GrayCodecError, RANS_LOW, SCALE, SCALE_BITS, SYMBOLS};

/// The encoder's constants for one symbol: where the state must move out 16 bits first, and
/// the division by its frequency as a multiplication by its reciprocal (Alverson, 1991).
pub(super) struct SymbolCoder {
    pub(super) x_max: u32,
    reciprocal: u32,
    bias: u32,
    complement: u16,
    shift: u8,
}

impl SymbolCoder {
    pub(super) fn new(start: u32, frequency: u32) -> Self {
        let x_max = ((RANS_LOW >> SCALE_BITS) << 16) * frequency;
        // At most 2^12 − 1, and the shift at most 11.
        let complement = (SCALE - frequency) as u16;
        if frequency < 2 {
            // x / 1 = x: the reciprocal 2^32 − 1 with the bias's extra SCALE − 1 gives it.
            Self {
                x_max,
                reciprocal: u32::MAX,
                shift: 0,
                bias: start + SCALE - 1,
                complement,
            }
        } else {
            let shift = 32 - (frequency - 1).leading_zeros();
            let reciprocal = (1u64 << (shift + 31)).div_ceil(u64::from(frequency));
            Self {
                x_max,
                reciprocal: reciprocal as u32,
                shift: (shift - 1) as u8,
                bias: start,
                complement,
            }
        }
    }

    /// The state after coding this symbol: (x / f) · 2^12 + x mod f + start.
    #[inline(always)]
    pub(super) fn push(&self, state: u32) -> u32 {
        let quotient = ((u64::from(state) * u64::from(self.reciprocal)) >> 32) as u32 >> self.shift;
        state + self.bias + quotient * u32::from(self.complement)
    }
}

/// One context's frequencies, their cumulative starts, and the decoder's slot lookup.
pub(super) struct Table {
    frequency: [u32; SYMBOLS],
    start: [u32; SYMBOLS],
    symbol_at: Vec<u8>,
}

impl Table {
    /// The frequencies for `counts`, scaled to sum to 2^12 with every present symbol kept.
    pub(super) fn from_counts(counts: &[u32; SYMBOLS]) -> Option<Self> {
        let total: u64 = counts.iter().map(|&c| u64::from(c)).sum();
        if total == 0 {
            return None;
        }
        let mut frequency = [0u32; SYMBOLS];
        for (f, &c) in frequency.iter_mut().zip(counts) {
            if c > 0 {
                *f = ((u64::from(c) * u64::from(SCALE) + total / 2) / total).max(1) as u32;
            }
        }
        // Rounding leaves the sum a little off: the most frequent symbols absorb it, where a
        // count moves their cost least.
        let mut sum: u32 = frequency.iter().sum();
        while sum != SCALE {
            let largest = (0..SYMBOLS).max_by_key(|&s| frequency[s]).expect("symbols");
            if sum < SCALE {
                frequency[largest] += SCALE - sum;
                sum = SCALE;
            } else {
                let take = (sum - SCALE).min(frequency[largest] - 1).max(1);
                frequency[largest] -= take;
                sum -= take;
            }
        }
        Some(Self::from_frequencies(frequency))
    }

    fn from_frequencies(frequency: [u32; SYMBOLS]) -> Self {
        let mut start = [0u32; SYMBOLS];
        let mut symbol_at = vec![0u8; SCALE as usize];
        let mut at = 0;
        for symbol in 0..SYMBOLS {
            start[symbol] = at;
            let end = at + frequency[symbol];
            symbol_at[at as usize..end as usize].fill(symbol as u8);
            at = end;
        }
        Self {
            frequency,
            start,
            symbol_at,
        }
    }

    /// The symbol a decoder's `state` holds, and the state without it (before moving a word
    /// in): the inverse of [`SymbolCoder::push`].
    #[inline(always)]
    pub(super) fn pop(&self, state: u32) -> (u8, u32) {
        let slot = state & (SCALE - 1);
        let symbol = self.symbol_at[slot as usize];
        let (start, frequency) = (
            self.start[usize::from(symbol)],
            self.frequency[usize::from(symbol)],
        );
        (symbol, frequency * (state >> SCALE_BITS) + slot - start)
    }

    pub(super) fn coders(&self) -> Vec<SymbolCoder> {
        (0..SYMBOLS)
            .map(|s| SymbolCoder::new(self.start[s], self.frequency[s]))
            .collect()
    }

    pub(super) fn write(&self, out: &mut Vec<u8>) {
        let present = self.frequency.iter().filter(|&&f| f > 0).count();
        write_varint(out, present as u32);
        let mut skipped = 0;
        for &f in &self.frequency {
            if f == 0 {
                skipped += 1;
            } else {
                write_varint(out, skipped);
                write_varint(out, f - 1);
                skipped = 0;
            }
        }
    }

    pub(super) fn read(input: &mut Input, context: usize) -> Result<Option<Self>, GrayCodecError> {
        let bad = |why: String| GrayCodecError::BadTable { context, why };
        let present = input.varint("tables")?;
        if present == 0 {
            return Ok(None);
        }
        if present as usize > SYMBOLS {
            return Err(bad(format!("{present} symbols, more than {SYMBOLS}")));
        }
        let mut frequency = [0u32; SYMBOLS];
        let (mut symbol, mut sum) = (0usize, 0u64);
        for _ in 0..present {
            symbol += input.varint("tables")? as usize;
            let f = u64::from(input.varint("tables")?) + 1;
            if symbol >= SYMBOLS {
                return Err(bad(format!("a symbol past {}", SYMBOLS - 1)));
            }
            sum += f;
            if sum > u64::from(SCALE) {
                return Err(bad(format!("frequencies past {SCALE}")));
            }
            frequency[symbol] = f as u32;
            symbol += 1;
        }
        if sum != u64::from(SCALE) {
            return Err(bad(format!("frequencies sum to {sum}, not {SCALE}")));
        }
        Ok(Some(Self::from_frequencies(frequency)))
    }
}

pub(super) fn write_varint(out: &mut Vec<u8>, mut value: u32) {
    while value >= 0x80 {
        out.push(value as u8 | 0x80);
        value >>= 7;
    }
    out.push(value as u8);
}

/// The bytes read so far; each read names the part it was reading when they ran out.
pub(super) struct Input<'a> {
    pub(super) bytes: &'a [u8],
    pub(super) at: usize,
}

impl Input<'_> {
    pub(super) fn take(
        &mut self,
        count: usize,
        part: &'static str,
    ) -> Result<&[u8], GrayCodecError> {
        let taken = self
            .bytes
            .get(self.at..self.at + count)
            .ok_or(GrayCodecError::Truncated(part))?;
        self.at += count;
        Ok(taken)
    }

    pub(super) fn u32(&mut self, part: &'static str) -> Result<u32, GrayCodecError> {
        let b = self.take(4, part)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }

    pub(super) fn varint(&mut self, part: &'static str) -> Result<u32, GrayCodecError> {
        let mut value = 0u32;
        for shift in (0..35).step_by(7) {
            let byte = self.take(1, part)?[0];
            value |= u32::from(byte & 0x7f) << shift;
            if byte < 0x80 {
                return Ok(value);
            }
        }
        Err(GrayCodecError::Truncated(part))
    }
}
