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

use glam::{IVec3, Vec3};

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
        for &t in &self.big {
            if visit(t) {
                return true;
            }
        }
        let (a, b) = self.cells(lo, hi);
        if Self::span((a, b)) > (self.starts.len() as i64) {
            // A query box larger than the table: every bucket once.
            for &t in &self.entries {
                if self.stamps[t as usize] != stamp {
                    self.stamps[t as usize] = stamp;
                    if visit(t) {
                        return true;
                    }
                }
            }
            return false;
        }
        for z in a.z..=b.z {
            for y in a.y..=b.y {
                for x in a.x..=b.x {
                    let bucket = (hash(IVec3::new(x, y, z)) & self.mask) as usize;
                    let (s, e) = (self.starts[bucket], self.starts[bucket + 1]);
                    for &t in &self.entries[s as usize..e as usize] {
                        if self.stamps[t as usize] != stamp {
                            self.stamps[t as usize] = stamp;
                            if visit(t) {
                                return true;
                            }
                        }
                    }
                }
            }
        }
        false
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
