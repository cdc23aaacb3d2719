//! A spatial hash of triangles (or of any boxes: the crossing meter puts
//! branch capsules in it) for exact range queries.
//!
//! Each triangle is registered in every cell its bounding box overlaps, so
//! a triangle within distance `r` of a point has a point in one of the
//! cells overlapping the query box `[p − r, p + r]` and is found there:
//! range queries are exact, whatever the cell size (which only sets the
//! cost). Cells hash into a power-of-two table; colliding cells share a
//! bucket, which costs extra distance tests but never a miss. Triangles
//! that would cover more than [`MAX_CELLS_PER_TRIANGLE`] cells go on a
//! short list every query visits. The table is built with a counting sort
//! into buffers that are kept between frames.

use glam::{IVec3, Vec3, Vec3A};

/// Triangles covering more cells than this are kept in a list that every
/// query scans, so one huge triangle cannot flood the table.
pub const MAX_CELLS_PER_TRIANGLE: i64 = 512;

/// The spatial hash (see the module docs).
#[derive(Clone, Debug, Default)]
pub struct TriangleGrid {
    cell: f32,
    mask: u32,
    /// `starts[b]..starts[b + 1]` are bucket `b`'s entries.
    starts: Vec<u32>,
    entries: Vec<u32>,
    big: Vec<u32>,
    /// Per triangle, the query that last visited it (deduplication).
    stamps: Vec<u32>,
    stamp: u32,
    /// Scratch: fill cursors of the counting sort.
    fill: Vec<u32>,
    /// Scratch: each triangle's cell range (`hi.x < lo.x` for big ones).
    ranges: Vec<(IVec3, IVec3)>,
}

fn hash(c: IVec3) -> u32 {
    (c.x as u32).wrapping_mul(0x9E37_79B1)
        ^ (c.y as u32).wrapping_mul(0x85EB_CA77)
        ^ (c.z as u32).wrapping_mul(0xC2B2_AE3D)
}

/// Calls `f` on every cell of the inclusive range `(a, b)`.
fn for_each_cell((a, b): (IVec3, IVec3), mut f: impl FnMut(IVec3)) {
    for z in a.z..=b.z {
        for y in a.y..=b.y {
            for x in a.x..=b.x {
                f(IVec3::new(x, y, z));
            }
        }
    }
}

impl TriangleGrid {
    fn cell_of(&self, p: Vec3) -> IVec3 {
        // Floor by truncation and a correction: `floor` is a libm call
        // on the baseline target, and this is the build's inner loop.
        let v = p / self.cell;
        let t = v.as_ivec3();
        let below = v.cmplt(t.as_vec3());
        t - IVec3::select(below, IVec3::ONE, IVec3::ZERO)
    }

    fn cells(&self, lo: Vec3, hi: Vec3) -> (IVec3, IVec3) {
        (self.cell_of(lo), self.cell_of(hi))
    }

    fn span((lo, hi): (IVec3, IVec3)) -> i64 {
        let d = (hi - lo).as_i64vec3() + 1;
        d.x * d.y * d.z
    }

    /// Rebuilds the table over `boxes` (the triangles' bounds, indexed by
    /// triangle) with cubic cells of side `cell` (positive, finite).
    pub fn build(&mut self, boxes: &[(Vec3, Vec3)], cell: f32) {
        self.cell = cell;
        self.big.clear();
        self.ranges.clear();
        let mut total = 0usize;
        for (i, &(lo, hi)) in boxes.iter().enumerate() {
            let range = self.cells(lo, hi);
            let n = Self::span(range);
            if n > MAX_CELLS_PER_TRIANGLE {
                self.big.push(i as u32);
                self.ranges.push((IVec3::ZERO, IVec3::NEG_ONE));
            } else {
                total += n as usize;
                self.ranges.push(range);
            }
        }
        let size = (total.max(boxes.len()) * 2).max(1024).next_power_of_two();
        self.mask = (size - 1) as u32;
        self.starts.clear();
        self.starts.resize(size + 1, 0);
        let mask = self.mask;
        for &range in &self.ranges {
            for_each_cell(range, |c| {
                self.starts[(hash(c) & mask) as usize + 1] += 1;
            });
        }
        for b in 0..size {
            self.starts[b + 1] += self.starts[b];
        }
        self.entries.clear();
        self.entries.resize(total, 0);
        // Fill from the back of each bucket, reusing `starts` as cursors
        // that end at each bucket's start.
        self.fill.clear();
        self.fill.extend_from_slice(&self.starts[1..]);
        for (i, &range) in self.ranges.iter().enumerate() {
            for_each_cell(range, |c| {
                let bucket = (hash(c) & mask) as usize;
                self.fill[bucket] -= 1;
                self.entries[self.fill[bucket] as usize] = i as u32;
            });
        }
        self.stamps.clear();
        self.stamps.resize(boxes.len(), 0);
        self.stamp = 0;
    }

    /// Calls `visit` once for every triangle that may come within the box
    /// `[lo, hi]` (every one that does, and some that do not) until it
    /// returns `true`; returns whether it did.
    pub fn any_near(&mut self, lo: Vec3, hi: Vec3, mut visit: impl FnMut(u32) -> bool) -> bool {
        self.stamp = self.stamp.wrapping_add(1);
        if self.stamp == 0 {
            self.stamps.fill(0);
            self.stamp = 1;
        }
        let stamp = self.stamp;
        let mut stamps = std::mem::take(&mut self.stamps);
        let found = self.scan(lo, hi, |t| {
            let seen = &mut stamps[t as usize];
            if *seen == stamp {
                return false;
            }
            *seen = stamp;
            visit(t)
        });
        self.stamps = stamps;
        found
    }

    /// [`TriangleGrid::any_near`] from a shared table (several threads may
    /// ask at once): a triangle in several cells of the box is visited
    /// once per cell, so this suits searches that stop at their first hit
    /// and whose misses cost little.
    pub fn any_near_shared(&self, lo: Vec3, hi: Vec3, visit: impl FnMut(u32) -> bool) -> bool {
        self.scan(lo, hi, visit)
    }

    /// Calls `visit` on the big triangles and on every entry of the cells
    /// of `[lo, hi]`, repeats included, until it returns `true`.
    fn scan(&self, lo: Vec3, hi: Vec3, mut visit: impl FnMut(u32) -> bool) -> bool {
        if self.big.iter().any(|&t| visit(t)) {
            return true;
        }
        let (a, b) = self.cells(lo, hi);
        if Self::span((a, b)) > (self.starts.len() as i64) {
            // A query box larger than the table: every bucket once.
            return self.entries.iter().any(|&t| visit(t));
        }
        for z in a.z..=b.z {
            for y in a.y..=b.y {
                for x in a.x..=b.x {
                    let bucket = (hash(IVec3::new(x, y, z)) & self.mask) as usize;
                    let (s, e) = (self.starts[bucket], self.starts[bucket + 1]);
                    if self.entries[s as usize..e as usize]
                        .iter()
                        .any(|&t| visit(t))
                    {
                        return true;
                    }
                }
            }
        }
        false
    }

    /// Calls `visit(i, j)`, `i < j`, once for every pair of `boxes` that
    /// meet (closed bounds), where `boxes` are those the table was last
    /// built over. Rather than one range query per box, each bucket's
    /// entries are paired among themselves, and a pair is taken only in
    /// the cell holding the low corner of the two boxes' overlap (both
    /// boxes cover that cell, and it is one cell, so one bucket): every
    /// meeting pair once, without the per-query stamps. Big boxes (on no
    /// bucket) are paired with every box directly.
    pub fn for_each_overlap(&self, boxes: &[(Vec3, Vec3)], mut visit: impl FnMut(u32, u32)) {
        let meet =
            |a: (Vec3, Vec3), b: (Vec3, Vec3)| !(b.0.cmpgt(a.1).any() || b.1.cmplt(a.0).any());
        let is_big = |k: usize| self.ranges[k].1.x < self.ranges[k].0.x;
        for &b in &self.big {
            for (k, &other) in boxes.iter().enumerate() {
                let k = k as u32;
                if k != b && !(is_big(k as usize) && k < b) && meet(boxes[b as usize], other) {
                    visit(b.min(k), b.max(k));
                }
            }
        }
        // Each bucket's boxes are copied next to each other before they
        // are paired: pairing read them through the entries' indices, a
        // scattered load per pair, and the pairs are several times the
        // entries (pairing took about half of the crossing meter's time:
        // 0.65-0.85 ms of a default morph's frame with a visitor that
        // does nothing).
        let mut local: Vec<(Vec3A, Vec3A, u32)> = Vec::new();
        for bucket in 0..self.starts.len().saturating_sub(1) {
            let entries =
                &self.entries[self.starts[bucket] as usize..self.starts[bucket + 1] as usize];
            if entries.len() < 2 {
                continue;
            }
            local.clear();
            for (x, &i) in entries.iter().enumerate() {
                // A box in two cells of one bucket is listed twice, next
                // to itself (the build fills each bucket in box order).
                if x == 0 || entries[x - 1] != i {
                    let (lo, hi) = boxes[i as usize];
                    local.push((lo.into(), hi.into(), i));
                }
            }
            for (x, &(lo, hi, i)) in local.iter().enumerate() {
                for &(other_lo, other_hi, j) in &local[x + 1..] {
                    if (other_lo.cmpgt(hi) | other_hi.cmplt(lo)).any() {
                        continue;
                    }
                    let corner = self.cell_of(lo.max(other_lo).into());
                    if (hash(corner) & self.mask) as usize == bucket {
                        visit(i.min(j), i.max(j));
                    }
                }
            }
        }
    }
}

/// Cells per axis of an [`Occupancy`]: 64³ bits, 32 KiB, which stays in
/// cache while a sweep reads every triangle's bounds against it.
const OCCUPANCY_CELLS: i32 = 64;

/// A coarse bitmap over a frame's bounds: which cells of a 64³ lattice a
/// set of boxes touches. Asking whether a box meets any of them costs a
/// few bit tests, so a pass over every triangle of a frame skips, at once,
/// the triangles near none of the few boxes a sweep looks for. Boxes
/// beyond the bounds are clamped onto its border cells, the same way when
/// marked and when asked, so two boxes that meet always meet here.
#[derive(Clone, Debug, Default)]
pub struct Occupancy {
    lo: Vec3,
    /// Cells per metre along each axis.
    scale: Vec3,
    bits: Vec<u64>,
}

impl Occupancy {
    /// Empties the map and spans it over `[lo, hi]`.
    pub fn reset(&mut self, lo: Vec3, hi: Vec3) {
        let n = OCCUPANCY_CELLS as f32;
        let extent = (hi - lo).max(Vec3::splat(1e-6));
        self.lo = lo;
        self.scale = Vec3::splat(n) / extent;
        let words = (OCCUPANCY_CELLS.pow(3) as usize).div_ceil(64);
        self.bits.clear();
        self.bits.resize(words, 0);
    }

    fn cell(&self, p: Vec3) -> IVec3 {
        let c = ((p - self.lo) * self.scale).as_ivec3();
        c.clamp(IVec3::ZERO, IVec3::splat(OCCUPANCY_CELLS - 1))
    }

    fn index(c: IVec3) -> usize {
        ((c.z * OCCUPANCY_CELLS + c.y) * OCCUPANCY_CELLS + c.x) as usize
    }

    /// Marks the cells the box `[lo, hi]` touches.
    pub fn mark(&mut self, lo: Vec3, hi: Vec3) {
        let (a, b) = (self.cell(lo), self.cell(hi));
        for_each_cell((a, b), |c| {
            let i = Self::index(c);
            self.bits[i / 64] |= 1 << (i % 64);
        });
    }

    /// Whether the box `[lo, hi]` touches a marked cell.
    pub fn any(&self, lo: Vec3, hi: Vec3) -> bool {
        let (a, b) = (self.cell(lo), self.cell(hi));
        for z in a.z..=b.z {
            for y in a.y..=b.y {
                for x in a.x..=b.x {
                    let i = Self::index(IVec3::new(x, y, z));
                    if self.bits[i / 64] & (1 << (i % 64)) != 0 {
                        return true;
                    }
                }
            }
        }
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Boxes from corners and sizes in a 10 m cube; some are flat or
    /// points, and a few span most of the cube.
    fn boxes() -> impl Strategy<Value = Vec<(Vec3, Vec3)>> {
        let coord = 0.0f32..10.0;
        let size = prop_oneof![Just(0.0f32), 0.0f32..1.0, 0.0f32..10.0];
        let one = (
            (coord.clone(), coord.clone(), coord),
            (size.clone(), size.clone(), size),
        )
            .prop_map(|((x, y, z), (a, b, c))| {
                let lo = Vec3::new(x, y, z);
                (lo, lo + Vec3::new(a, b, c))
            });
        prop::collection::vec(one, 0..120)
    }

    fn brute_force(boxes: &[(Vec3, Vec3)]) -> Vec<(u32, u32)> {
        let mut pairs = Vec::new();
        for (i, a) in boxes.iter().enumerate() {
            for (j, b) in boxes.iter().enumerate().skip(i + 1) {
                if !(b.0.cmpgt(a.1).any() || b.1.cmplt(a.0).any()) {
                    pairs.push((i as u32, j as u32));
                }
            }
        }
        pairs
    }

    proptest! {
        /// Every meeting pair once, whatever the cell: fine cells put big
        /// boxes on the list every query visits, and a small table makes
        /// cells share buckets.
        #[test]
        fn overlaps_are_every_meeting_pair_once(boxes in boxes(), cell in prop_oneof![Just(0.05f32), 0.2f32..3.0]) {
            let mut grid = TriangleGrid::default();
            grid.build(&boxes, cell);
            let mut found = Vec::new();
            grid.for_each_overlap(&boxes, |i, j| found.push((i, j)));
            let visited = found.len();
            found.sort_unstable();
            found.dedup();
            prop_assert_eq!(visited, found.len(), "a pair was visited twice");
            prop_assert_eq!(found, brute_force(&boxes));
        }
    }
}
