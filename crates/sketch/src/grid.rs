//! [`PointGrid`]: the nearest of many points on screen, found in a uniform
//! grid instead of by scanning them all (the foliage fit asks for the leaf
//! nearest to a few hundred points per pass, among up to tens of
//! thousands).

use glam::Vec2;

use crate::polygon;

/// Points with ids, bucketed in a square grid of about one point per cell.
pub(crate) struct PointGrid {
    /// Each point and its id.
    at: Vec<(Vec2, u32)>,
    /// Lower corner, cell size and cells per side.
    lo: Vec2,
    cell: f32,
    side: usize,
    /// Each cell's points: `order[start[c]..start[c + 1]]`, indices into
    /// `at`.
    start: Vec<u32>,
    order: Vec<u32>,
}

impl PointGrid {
    /// The grid of `at` (points and their ids).
    pub(crate) fn new(at: Vec<(Vec2, u32)>) -> PointGrid {
        let (lo, hi) = polygon::bounds(&at.iter().map(|a| a.0).collect::<Vec<_>>())
            .unwrap_or((Vec2::ZERO, Vec2::ZERO));
        let side = ((at.len() as f32).sqrt() as usize).clamp(1, 256);
        let cell = ((hi - lo).max_element() / side as f32).max(1e-6);
        let mut grid = PointGrid {
            at,
            lo,
            cell,
            side,
            start: Vec::new(),
            order: Vec::new(),
        };
        grid.bucket();
        grid
    }

    /// Fills the cells (a counting sort of the points by cell).
    fn bucket(&mut self) {
        let cells: Vec<usize> = self.at.iter().map(|&(p, _)| self.cell_of(p)).collect();
        let mut start = vec![0u32; self.side * self.side + 1];
        for &c in &cells {
            start[c + 1] += 1;
        }
        for c in 0..self.side * self.side {
            start[c + 1] += start[c];
        }
        let mut fill = start.clone();
        self.order = vec![0; cells.len()];
        for (k, &c) in cells.iter().enumerate() {
            self.order[fill[c] as usize] = k as u32;
            fill[c] += 1;
        }
        self.start = start;
    }

    /// The cell of `p`, clamped into the grid.
    fn coords(&self, p: Vec2) -> (i64, i64) {
        let q = ((p - self.lo) / self.cell).floor();
        let max = self.side as i64 - 1;
        ((q.x as i64).clamp(0, max), (q.y as i64).clamp(0, max))
    }

    fn cell_of(&self, p: Vec2) -> usize {
        let (x, y) = self.coords(p);
        y as usize * self.side + x as usize
    }

    /// The id of the point nearest to `p` (`None` without points): ring
    /// by ring of cells around `p`'s.
    pub(crate) fn nearest(&self, p: Vec2) -> Option<u32> {
        let (cx, cy) = self.coords(p);
        let mut best: Option<(f32, u32)> = None;
        for ring in 0..self.side as i64 {
            // Every point of this ring or farther is at least this far.
            let bound = (ring as f32 - 1.0).max(0.0) * self.cell;
            if best.is_some_and(|(d, _)| d <= bound) {
                break;
            }
            for (x, y) in ring_cells(cx, cy, ring, self.side as i64) {
                let c = y as usize * self.side + x as usize;
                for &i in &self.order[self.start[c] as usize..self.start[c + 1] as usize] {
                    let (q, id) = self.at[i as usize];
                    let d = q.distance(p);
                    if best.is_none_or(|(b, _)| d < b) {
                        best = Some((d, id));
                    }
                }
            }
        }
        best.map(|(_, id)| id)
    }
}

/// The cells at Chebyshev distance `ring` from `(cx, cy)` inside a grid of
/// `side`² cells.
fn ring_cells(cx: i64, cy: i64, ring: i64, side: i64) -> impl Iterator<Item = (i64, i64)> {
    let inside = move |(x, y): &(i64, i64)| (0..side).contains(x) && (0..side).contains(y);
    let range = -ring..=ring;
    range
        .flat_map(move |d| {
            let edges = [(cx + d, cy - ring), (cx + d, cy + ring)];
            let sides = [(cx - ring, cy + d), (cx + ring, cy + d)];
            let sides_ok = d.abs() < ring;
            edges
                .into_iter()
                .take(if ring == 0 { 1 } else { 2 })
                .chain(sides.into_iter().filter(move |_| sides_ok))
        })
        .filter(inside)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The rings around any cell cover the grid, each cell once.
    #[test]
    fn rings_cover_the_grid_once() {
        for side in [1i64, 2, 5] {
            for (cx, cy) in [(0, 0), (side - 1, 0), (side / 2, side / 2)] {
                let mut seen: Vec<(i64, i64)> = (0..side)
                    .flat_map(|r| ring_cells(cx, cy, r, side))
                    .collect();
                seen.sort_unstable();
                let all: Vec<(i64, i64)> = (0..side)
                    .flat_map(|x| (0..side).map(move |y| (x, y)))
                    .collect();
                assert_eq!(seen, all, "side {side} from ({cx}, {cy})");
            }
        }
    }

    /// The grid finds what a scan of every point finds, from inside and
    /// outside the points' bounds.
    #[test]
    fn the_nearest_point_is_the_scanned_one() {
        let at: Vec<(Vec2, u32)> = (0..500u32)
            .map(|i| {
                let a = i as f32 * 2.399;
                let r = (i as f32).sqrt() * 0.05;
                (
                    Vec2::new(a.cos(), a.sin()) * r + Vec2::new(0.3 * r * r, 0.0),
                    i,
                )
            })
            .collect();
        let grid = PointGrid::new(at.clone());
        for k in 0..200 {
            let a = k as f32 * 0.77;
            let p = Vec2::new(a.cos(), a.sin()) * (k as f32 * 0.01);
            let scanned = at
                .iter()
                .min_by(|x, y| x.0.distance(p).total_cmp(&y.0.distance(p)))
                .map(|x| x.1);
            let found = grid.nearest(p).unwrap();
            assert_eq!(
                at[found as usize].0.distance(p),
                at[scanned.unwrap() as usize].0.distance(p),
                "at {p}"
            );
        }
        assert_eq!(PointGrid::new(Vec::new()).nearest(Vec2::ZERO), None);
    }
}
