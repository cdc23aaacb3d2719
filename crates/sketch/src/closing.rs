//! Morphological closing of a square raster by a disc, on bit rows.
//!
//! The foliage outline is the projected leaves closed by a disc of the
//! closing radius ([`crate::SketchOptions::closing_radius`]): dilated (a
//! pixel is set when a set pixel's centre lies within the radius), then
//! eroded (a pixel stays set when no clear pixel, and no pixel outside the
//! grid, lies within the radius). Both are exact on pixel centres.
//!
//! Written by hand: it runs on every measured frame and on every trial
//! pose of the foliage fit, and a disc's rows on 64-bit words do in a few
//! thousand word operations what two exact distance transforms (the first
//! version) did in a few hundred thousand float operations, with the same
//! pixels set. The image crates offer either square/diamond structuring
//! elements on byte images or distance transforms, not this.

/// Closes `mask` (`g` × `g`, row-major) by the disc of squared radius `r2`
/// pixels²: pixels whose centres are within `√r2` of each other touch.
pub(crate) fn close(mask: &mut [bool], g: usize, r2: f32) {
    if r2.is_nan() || r2 < 0.0 || g == 0 {
        return;
    }
    let disc = Disc::new(r2, g);
    let set = Rows::pack(mask, g, false);
    let dilated = disc.dilate(&set, false);
    // Erosion is the dilation of the clear pixels, the outside counting as
    // clear: a pixel stays when none of them is within reach.
    let clear = dilated.not();
    let reached = disc.dilate(&clear, true);
    for (y, row) in mask.chunks_exact_mut(g).enumerate() {
        for (x, m) in row.iter_mut().enumerate() {
            *m = dilated.get(x, y) && !reached.get(x, y);
        }
    }
}

/// A disc's half-widths: row `dy` of the disc spans `[-w, w]` with
/// `w = half[|dy|]`.
struct Disc {
    half: Vec<usize>,
}

impl Disc {
    /// The disc of squared radius `r2`, no wider than the grid needs.
    fn new(r2: f32, g: usize) -> Disc {
        let reach = |d: usize| (d * d) as f32 <= r2;
        let mut half = Vec::new();
        while half.len() < g && reach(half.len()) {
            let dy = half.len();
            let mut w = 0;
            while w < g && ((w + 1) * (w + 1) + dy * dy) as f32 <= r2 {
                w += 1;
            }
            half.push(w);
        }
        Disc { half }
    }

    /// Every pixel within the disc of a set pixel of `rows`; rows and
    /// columns outside the grid count as `outside`.
    fn dilate(&self, rows: &Rows, outside: bool) -> Rows {
        let spread = self.spread(rows, outside);
        let widest = self.half.len();
        let mut out = Rows::empty(rows.g, rows.words);
        for y in 0..rows.g {
            let target = out.row_mut(y);
            for dy in -(widest as isize - 1)..widest as isize {
                let w = self.half[dy.unsigned_abs()];
                let source = y as isize + dy;
                if source < 0 || source >= rows.g as isize {
                    if outside {
                        target.fill(!0);
                    }
                    continue;
                }
                let from = &spread[w][source as usize * rows.words..][..rows.words];
                for (t, &f) in target.iter_mut().zip(from) {
                    *t |= f;
                }
            }
        }
        out
    }

    /// Per half-width `w` the disc uses, every row spread sideways by `w`:
    /// `spread[w]` holds, flat, each row ORed with itself shifted by up to
    /// `w` either way.
    fn spread(&self, rows: &Rows, outside: bool) -> Vec<Vec<u64>> {
        let widest = self.half.first().copied().unwrap_or(0);
        let mut spread = vec![rows.bits.clone()];
        let mut shifted = vec![0u64; rows.words];
        for w in 1..=widest {
            let mut next = spread[w - 1].clone();
            for y in 0..rows.g {
                let row = rows.row(y);
                let at = &mut next[y * rows.words..][..rows.words];
                for up in [true, false] {
                    shift(row, w, up, outside, &mut shifted);
                    for (a, &s) in at.iter_mut().zip(&shifted) {
                        *a |= s;
                    }
                }
            }
            spread.push(next);
        }
        spread
    }
}

/// `row` shifted by `k` bits toward higher (`up`) or lower pixel indices
/// into `out`, `fill` shifted in from outside the row's words.
fn shift(row: &[u64], k: usize, up: bool, fill: bool, out: &mut [u64]) {
    let n = row.len();
    let fill_word = if fill { !0u64 } else { 0 };
    let word = |i: isize| {
        if i < 0 || i >= n as isize {
            fill_word
        } else {
            row[i as usize]
        }
    };
    let (q, b) = ((k / 64) as isize, (k % 64) as u32);
    for (i, o) in out.iter_mut().enumerate() {
        let i = i as isize;
        *o = if up {
            let (hi, lo) = (word(i - q), word(i - q - 1));
            if b == 0 {
                hi
            } else {
                (hi << b) | (lo >> (64 - b))
            }
        } else {
            let (lo, hi) = (word(i + q), word(i + q + 1));
            if b == 0 {
                lo
            } else {
                (lo >> b) | (hi << (64 - b))
            }
        };
    }
}

/// A `g` × `g` raster as bit rows of `words` 64-bit words each; the bits
/// past `g` in a row's last word hold what the outside counts as.
struct Rows {
    g: usize,
    words: usize,
    bits: Vec<u64>,
}

impl Rows {
    fn empty(g: usize, words: usize) -> Rows {
        Rows {
            g,
            words,
            bits: vec![0; g * words],
        }
    }

    /// `mask` packed, the padding bits set to `outside`.
    fn pack(mask: &[bool], g: usize, outside: bool) -> Rows {
        let mut rows = Rows::empty(g, g.div_ceil(64));
        for y in 0..g {
            let row = rows.row_mut(y);
            for (x, &m) in mask[y * g..(y + 1) * g].iter().enumerate() {
                row[x / 64] |= u64::from(m) << (x % 64);
            }
        }
        rows.pad(outside);
        rows
    }

    /// Every pixel flipped; the padding marks the outside as set.
    fn not(&self) -> Rows {
        let mut out = Rows {
            g: self.g,
            words: self.words,
            bits: self.bits.iter().map(|&b| !b).collect(),
        };
        out.pad(true);
        out
    }

    fn pad(&mut self, outside: bool) {
        let used = self.g % 64;
        if used == 0 {
            return;
        }
        let padding = !0u64 << used;
        let words = self.words;
        for y in 0..self.g {
            let last = &mut self.row_mut(y)[words - 1];
            *last = if outside {
                *last | padding
            } else {
                *last & !padding
            };
        }
    }

    fn row(&self, y: usize) -> &[u64] {
        &self.bits[y * self.words..(y + 1) * self.words]
    }

    fn row_mut(&mut self, y: usize) -> &mut [u64] {
        &mut self.bits[y * self.words..(y + 1) * self.words]
    }

    fn get(&self, x: usize, y: usize) -> bool {
        self.bits[y * self.words + x / 64] >> (x % 64) & 1 == 1
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// The closing by its definition: dilate, then erode with the outside
    /// clear, every pair of pixel centres within reach compared.
    fn brute(mask: &[bool], g: usize, r2: f32) -> Vec<bool> {
        let r = r2.sqrt() as isize + 1;
        let within = |i: usize| {
            let (x, y) = ((i % g) as isize, (i / g) as isize);
            let g = g as isize;
            (-r..=r)
                .flat_map(move |dy| (-r..=r).map(move |dx| (x + dx, y + dy, dx, dy)))
                .filter(move |&(p, q, dx, dy)| {
                    p >= 0 && q >= 0 && p < g && q < g && (dx * dx + dy * dy) as f32 <= r2
                })
                .map(move |(p, q, _, _)| (q * g + p) as usize)
        };
        let dilated: Vec<bool> = (0..g * g).map(|i| within(i).any(|j| mask[j])).collect();
        (0..g * g)
            .map(|i| {
                let (x, y) = (i % g, i / g);
                let inside = within(i).all(|j| dilated[j]);
                // The outside: the nearest outside pixel is one past an edge.
                let edge = x.min(y).min(g - 1 - x).min(g - 1 - y) + 1;
                dilated[i] && inside && (edge * edge) as f32 > r2
            })
            .collect()
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(32))]
        /// Bit rows give the pixels the definition gives, across word
        /// boundaries (grids of 1–3 words) and radii up to past a word.
        #[test]
        fn closing_matches_its_definition(
            g in prop::sample::select(vec![5usize, 31, 64, 70, 130]),
            r2 in 0.0f32..80.0,
            seed in any::<u64>(),
            density in 0.0f64..0.3,
        ) {
            let mut state = seed | 1;
            let mask: Vec<bool> = (0..g * g)
                .map(|_| {
                    state ^= state << 13;
                    state ^= state >> 7;
                    state ^= state << 17;
                    (state % 1000) as f64 / 1000.0 < density
                })
                .collect();
            let mut closed = mask.clone();
            close(&mut closed, g, r2);
            prop_assert_eq!(closed, brute(&mask, g, r2));
        }
    }

    /// A shift of a whole word or more carries whole words.
    #[test]
    fn long_shifts_carry_words() {
        let row = [1u64, 0, 0];
        let mut out = [0u64; 3];
        shift(&row, 64, true, false, &mut out);
        assert_eq!(out, [0, 1, 0]);
        shift(&row, 129, true, false, &mut out);
        assert_eq!(out, [0, 0, 2]);
        shift(&[0, 0, 4], 130, false, true, &mut out);
        assert_eq!(out, [1 | (!0u64 << 62), !0, !0]);
    }
}
