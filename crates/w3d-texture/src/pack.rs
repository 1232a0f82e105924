//! Chart packing: each chart is turned to its minimum-area bounding rectangle,
//! rasterised conservatively into texel cells and grown by the padding, then placed
//! largest first on a bit grid of the atlas at the lowest free position (4 rotations by
//! 90°; row-span search that jumps over occupied runs, so holes left by earlier charts
//! are filled). The texel scale is bisected so every chart fits the square atlas.

use glam::DVec2;
use rayon::prelude::*;

/// Where one chart goes: rotate its layout by `rotation · 90°`, scale by the packing's
/// texel scale, add `offset` (texels, v up).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Placement {
    pub rotation: u8,
    pub offset: DVec2,
}

/// The result of [`pack`].
#[derive(Debug, Clone)]
pub(crate) struct Packing {
    /// Texels per world unit.
    pub scale: f64,
    /// One placement per chart, in input order.
    pub placements: Vec<Placement>,
}

impl Packing {
    /// Atlas texel coordinates (v up) of a layout point of chart `chart`.
    pub fn texel(&self, chart: usize, p: DVec2) -> DVec2 {
        let pl = self.placements[chart];
        rotate(p, pl.rotation) * self.scale + pl.offset
    }
}

/// `p` turned by `r · 90°` counter-clockwise.
fn rotate(p: DVec2, r: u8) -> DVec2 {
    match r & 3 {
        0 => p,
        1 => DVec2::new(-p.y, p.x),
        2 => -p,
        _ => DVec2::new(p.y, -p.x),
    }
}

/// A chart rasterised at one scale and rotation: the runs of occupied cells of each row
/// of its box (padding included).
struct Shape {
    /// Texel coordinates of the box's lower-left cell corner, in scaled rotated layout space.
    lo: DVec2,
    /// Runs `(row, first, one past last)` of occupied cells.
    spans: Vec<(u32, u32, u32)>,
    /// Box width and height in cells.
    width: usize,
    height: usize,
    /// Indices of the (up to 4) longest spans.
    widest: Vec<usize>,
}

/// The x range of triangle `t` within the horizontal strip `y0 ≤ y ≤ y1` (`None` if the
/// triangle misses the strip).
fn strip_range(t: [DVec2; 3], y0: f64, y1: f64) -> Option<(f64, f64)> {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    let mut add = |x: f64| {
        lo = lo.min(x);
        hi = hi.max(x);
    };
    for k in 0..3 {
        let (a, b) = (t[k], t[(k + 1) % 3]);
        if a.y >= y0 && a.y <= y1 {
            add(a.x);
        }
        for y in [y0, y1] {
            if (a.y < y && b.y > y) || (a.y > y && b.y < y) {
                add(a.x + (b.x - a.x) * (y - a.y) / (b.y - a.y));
            }
        }
    }
    (lo <= hi).then_some((lo, hi))
}

/// Conservative rasterisation: every cell a triangle touches is occupied; then the
/// occupancy is grown by `padding` cells in each direction (square structuring element).
/// The chart's shapes for the four rotations (the grid is invariant under quarter turns,
/// so the rotated shapes are the rotated cell sets of the unrotated one).
fn shapes(uv: &[DVec2], triangles: &[[u32; 3]], scale: f64, padding: i32) -> [Shape; 4] {
    let q: Vec<DVec2> = uv.iter().map(|p| *p * scale).collect();
    let (min, max) = q
        .iter()
        .fold((DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY)), |(l, h), p| (l.min(*p), h.max(*p)));
    let base = min.floor();
    let core_h = (max.y.floor() - base.y) as usize + 1;
    let mut core: Vec<Vec<(i32, i32)>> = vec![Vec::new(); core_h];
    for t in triangles {
        let c = t.map(|v| q[v as usize] - base);
        let y_lo = c[0].y.min(c[1].y).min(c[2].y).floor().max(0.0) as usize;
        let y_hi = (c[0].y.max(c[1].y).max(c[2].y).floor() as usize).min(core_h - 1);
        for (y, row) in core.iter_mut().enumerate().take(y_hi + 1).skip(y_lo) {
            if let Some((a, b)) = strip_range(c, y as f64, y as f64 + 1.0) {
                row.push((a.floor().max(0.0) as i32, b.floor() as i32 + 1));
            }
        }
    }
    // Occupancy of the padded box: each core row's cells, grown by the padding
    // horizontally, then vertically.
    let p = padding as usize;
    let width = core.iter().flatten().map(|r| r.1).max().unwrap_or(0).max(0) as usize + 2 * p;
    let height = core_h + 2 * p;
    let mut horizontal = vec![false; width * core_h];
    for (y, cells) in core.iter().enumerate() {
        for &(a, b) in cells {
            horizontal[y * width + a as usize..y * width + b as usize + 2 * p].fill(true);
        }
    }
    // Vertical growth: a cell is occupied if one of the 2p + 1 core rows at or below it is.
    let mut occupied = vec![false; width * height];
    let mut last = vec![usize::MAX; width];
    for y in 0..height {
        for x in 0..width {
            if y < core_h && horizontal[y * width + x] {
                last[x] = y;
            }
            occupied[y * width + x] = last[x] != usize::MAX && last[x] + 2 * p >= y;
        }
    }
    let lo = base - DVec2::splat(padding as f64);
    let size = DVec2::new(width as f64, height as f64);
    [0u8, 1, 2, 3].map(|r| {
        let corners = [lo, lo + size, DVec2::new(lo.x, lo.y + size.y), DVec2::new(lo.x + size.x, lo.y)];
        let lo_r = corners.iter().fold(DVec2::splat(f64::INFINITY), |m, c| m.min(rotate(*c, r)));
        let (w_r, h_r) = if r % 2 == 0 { (width, height) } else { (height, width) };
        let mut cells = vec![false; w_r * h_r];
        for y in 0..height {
            for x in 0..width {
                if occupied[y * width + x] {
                    // Cell (x, y) turned by r quarter turns about the box.
                    let (xr, yr) = match r {
                        0 => (x, y),
                        1 => (height - 1 - y, x),
                        2 => (width - 1 - x, height - 1 - y),
                        _ => (y, width - 1 - x),
                    };
                    cells[yr * w_r + xr] = true;
                }
            }
        }
        let mut spans = Vec::new();
        for y in 0..h_r {
            let row = &cells[y * w_r..(y + 1) * w_r];
            let mut x = 0;
            while x < w_r {
                if row[x] {
                    let start = x;
                    while x < w_r && row[x] {
                        x += 1;
                    }
                    spans.push((y as u32, start as u32, x as u32));
                } else {
                    x += 1;
                }
            }
        }
        let mut widest: Vec<usize> = (0..spans.len()).collect();
        widest.sort_by_key(|&k| std::cmp::Reverse(spans[k].2 - spans[k].1));
        widest.truncate(4);
        Shape { lo: lo_r, spans, width: w_r, height: h_r, widest }
    })
}

/// Occupancy of the atlas cells, one bit per cell, rows of 64-bit words.
struct Grid {
    width: usize,
    height: usize,
    words: usize,
    bits: Vec<u64>,
    /// Longest run of free cells per row.
    longest_free: Vec<usize>,
}

impl Grid {
    fn new(width: usize, height: usize) -> Self {
        let words = width.div_ceil(64);
        Grid { width, height, words, bits: vec![0; words * height], longest_free: vec![width; height] }
    }

    fn update_longest_free(&mut self, y: usize) {
        let (mut best, mut run) = (0, 0);
        for x in 0..self.width {
            if self.bits[y * self.words + x / 64] >> (x % 64) & 1 == 0 {
                run += 1;
                best = best.max(run);
            } else {
                run = 0;
            }
        }
        self.longest_free[y] = best;
    }

    /// First occupied cell of row `y` in `[from, to)`.
    fn first_occupied(&self, y: usize, from: usize, to: usize) -> Option<usize> {
        let row = &self.bits[y * self.words..(y + 1) * self.words];
        let mut x = from;
        while x < to {
            let (w, b) = (x / 64, x % 64);
            let word = row[w] >> b;
            if word != 0 {
                let hit = x + word.trailing_zeros() as usize;
                return (hit < to).then_some(hit);
            }
            x += 64 - b;
        }
        None
    }

    /// First free cell of row `y` at or after `from` (`width` if none).
    fn first_free(&self, y: usize, from: usize) -> usize {
        let row = &self.bits[y * self.words..(y + 1) * self.words];
        let mut x = from;
        while x < self.width {
            let (w, b) = (x / 64, x % 64);
            let word = !row[w] >> b;
            if word != 0 {
                return (x + word.trailing_zeros() as usize).min(self.width);
            }
            x += 64 - b;
        }
        self.width
    }

    fn fill(&mut self, y: usize, from: usize, to: usize) {
        for x in from..to {
            self.bits[y * self.words + x / 64] |= 1 << (x % 64);
        }
    }

    /// The lowest row (then leftmost column) where `shape` fits, with its top at or
    /// below `max_top`.
    fn find(&self, shape: &Shape, max_top: usize) -> Option<(usize, usize)> {
        let (w, h) = (shape.width, shape.height);
        if w > self.width || h > max_top.min(self.height) {
            return None;
        }
        let x_max = self.width - w;
        // The span that blocked last is tried first: obstacles tend to repeat.
        let mut hint = 0usize;
        for y in 0..=max_top.min(self.height) - h {
            // Rows without a free run as long as the widest spans rule `y` out at once.
            if shape.widest.iter().any(|&k| {
                let (r, a, b) = shape.spans[k];
                self.longest_free[y + r as usize] < (b - a) as usize
            }) {
                continue;
            }
            let mut x = 0usize;
            'scan: while x <= x_max {
                for k in std::iter::once(hint).chain(0..shape.spans.len()) {
                    let (r, a, b) = shape.spans[k];
                    let (r, a, b) = (r as usize, a as usize, b as usize);
                    if let Some(hit) = self.first_occupied(y + r, x + a, x + b) {
                        x = self.first_free(y + r, hit) - a;
                        hint = k;
                        continue 'scan;
                    }
                }
                return Some((x, y));
            }
        }
        None
    }

    fn place(&mut self, shape: &Shape, x: usize, y: usize) {
        for &(r, a, b) in &shape.spans {
            self.fill(y + r as usize, x + a as usize, x + b as usize);
        }
        for r in 0..shape.height {
            self.update_longest_free(y + r);
        }
    }
}

/// Places the shapes (4 rotations per chart) in the given order, each at the position
/// with the lowest top (then lowest row, leftmost column) over its rotations, in a
/// `size × size` grid. Returns per chart `(rotation, x, y)`, or `None` if one does not fit.
fn place_all(shapes: &[[Shape; 4]], order: &[usize], size: usize) -> Option<Vec<(u8, usize, usize)>> {
    let mut grid = Grid::new(size, size);
    let mut placed = vec![(0u8, 0usize, 0usize); shapes.len()];
    for &c in order {
        // Rotations in turn, each search bounded by the best top so far.
        let mut best: Option<(usize, usize, usize, u8)> = None; // (top, y, x, rotation)
        for (r, shape) in shapes[c].iter().enumerate() {
            let limit = best.map_or(size, |b| b.0);
            if let Some((x, y)) = grid.find(shape, limit) {
                let candidate = (y + shape.height, y, x, r as u8);
                if best.is_none_or(|b| candidate < b) {
                    best = Some(candidate);
                }
            }
        }
        let (_, y, x, r) = best?;
        grid.place(&shapes[c][r as usize], x, y);
        placed[c] = (r, x, y);
    }
    Some(placed)
}

/// Turns each layout to its minimum-area bounding rectangle (the best hull-edge
/// direction), in place, and moves its box to the origin.
pub(crate) fn orient_min_area(uv: &mut [DVec2]) {
    let hull = convex_hull(uv);
    if hull.len() < 3 {
        return;
    }
    let mut best = (f64::INFINITY, DVec2::X);
    for k in 0..hull.len() {
        let d = (hull[(k + 1) % hull.len()] - hull[k]).normalize_or_zero();
        if d == DVec2::ZERO {
            continue;
        }
        let (mut lo, mut hi) = (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY));
        for p in &hull {
            let q = DVec2::new(p.dot(d), d.perp_dot(*p));
            lo = lo.min(q);
            hi = hi.max(q);
        }
        let area = (hi - lo).x * (hi - lo).y;
        if area < best.0 {
            best = (area, d);
        }
    }
    let d = best.1;
    for p in uv.iter_mut() {
        *p = DVec2::new(p.dot(d), d.perp_dot(*p));
    }
    let lo = uv.iter().fold(DVec2::splat(f64::INFINITY), |m, p| m.min(*p));
    for p in uv.iter_mut() {
        *p -= lo;
    }
}

/// Convex hull (Andrew's monotone chain), counter-clockwise.
fn convex_hull(points: &[DVec2]) -> Vec<DVec2> {
    let mut p = points.to_vec();
    p.sort_by(|a, b| a.x.total_cmp(&b.x).then(a.y.total_cmp(&b.y)));
    p.dedup();
    if p.len() < 3 {
        return p;
    }
    let mut hull: Vec<DVec2> = Vec::with_capacity(2 * p.len());
    for pass in 0..2 {
        let start = hull.len();
        let iter: Box<dyn Iterator<Item = &DVec2>> =
            if pass == 0 { Box::new(p.iter()) } else { Box::new(p.iter().rev()) };
        for &q in iter {
            while hull.len() >= start + 2 {
                let (a, b) = (hull[hull.len() - 2], hull[hull.len() - 1]);
                if (b - a).perp_dot(q - a) <= 0.0 {
                    hull.pop();
                } else {
                    break;
                }
            }
            hull.push(q);
        }
        hull.pop();
    }
    hull
}

/// Packs charts (layouts in world units, boxes at the origin) into a square atlas of
/// `size` texels with `padding` empty texels around each chart, at the largest texel
/// scale found (bisection to 2 %, at most 16 packings) at which every chart fits.
pub(crate) fn pack(charts: &[(&[DVec2], &[[u32; 3]])], areas: &[f64], size: u32, padding: u32) -> Option<Packing> {
    let width = size as usize;
    let total: f64 = areas.iter().sum();
    if total <= 0.0 || charts.is_empty() {
        return None;
    }
    let mut order: Vec<usize> = (0..charts.len()).collect();
    order.sort_by(|&a, &b| areas[b].total_cmp(&areas[a]).then(a.cmp(&b)));
    let attempt = |scale: f64| {
        let shapes: Vec<[Shape; 4]> =
            charts.par_iter().map(|(uv, tris)| shapes(uv, tris, scale, padding as i32)).collect();
        let placed = place_all(&shapes, &order, width)?;
        Some(Packing {
            scale,
            placements: placed
                .iter()
                .enumerate()
                .map(|(c, &(r, x, y))| Placement {
                    rotation: r,
                    offset: DVec2::new(x as f64, y as f64) - shapes[c][r as usize].lo,
                })
                .collect(),
        })
    };
    // Bisection on the scale between one that fits and one that does not.
    let mut scale = (0.65 * (width * width) as f64 / total).sqrt();
    let (mut lo, mut hi) = (0.0f64, f64::INFINITY);
    let mut best = None;
    for _ in 0..16 {
        match attempt(scale) {
            Some(packing) => {
                lo = scale;
                best = Some(packing);
                scale = if hi.is_finite() { 0.5 * (lo + hi) } else { scale * 1.06 };
            }
            None => {
                hi = scale;
                scale = if lo > 0.0 { 0.5 * (lo + hi) } else { scale / 1.06 };
            }
        }
        if lo > 0.0 && hi / lo < 1.02 {
            break;
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square(side: f64) -> (Vec<DVec2>, Vec<[u32; 3]>) {
        let uv = vec![DVec2::ZERO, DVec2::new(side, 0.0), DVec2::new(side, side), DVec2::new(0.0, side)];
        (uv, vec![[0, 1, 2], [0, 2, 3]])
    }

    #[test]
    fn squares_pack_without_overlap_and_tightly() {
        let sq: Vec<(Vec<DVec2>, Vec<[u32; 3]>)> = (0..16).map(|i| square(1.0 + 0.05 * (i % 4) as f64)).collect();
        let charts: Vec<(&[DVec2], &[[u32; 3]])> = sq.iter().map(|(u, t)| (u.as_slice(), t.as_slice())).collect();
        let areas: Vec<f64> = sq.iter().map(|(u, _)| u[2].x * u[2].y).collect();
        let packing = pack(&charts, &areas, 256, 2).unwrap();
        let boxes: Vec<(DVec2, DVec2)> = (0..sq.len())
            .map(|c| {
                let a = packing.texel(c, sq[c].0[0]);
                let b = packing.texel(c, sq[c].0[2]);
                (a.min(b), a.max(b))
            })
            .collect();
        for (i, a) in boxes.iter().enumerate() {
            assert!(a.0.x >= 0.0 && a.0.y >= 0.0 && a.1.x <= 256.0 && a.1.y <= 256.0, "{a:?}");
            for b in &boxes[i + 1..] {
                let gap_x = (b.0.x - a.1.x).max(a.0.x - b.1.x);
                let gap_y = (b.0.y - a.1.y).max(a.0.y - b.1.y);
                assert!(gap_x.max(gap_y) >= 2.0, "{a:?} {b:?}");
            }
        }
        let used: f64 = areas.iter().sum::<f64>() * packing.scale * packing.scale / (256.0 * 256.0);
        assert!(used > 0.7, "utilisation {used}");
    }

    #[test]
    fn min_area_orientation_straightens_a_rotated_rectangle() {
        let a = 0.3f64;
        let (c, s) = (a.cos(), a.sin());
        let mut uv: Vec<DVec2> = [(0.0, 0.0), (4.0, 0.0), (4.0, 1.0), (0.0, 1.0)]
            .iter()
            .map(|&(x, y)| DVec2::new(c * x - s * y, s * x + c * y))
            .collect();
        orient_min_area(&mut uv);
        let hi = uv.iter().fold(DVec2::ZERO, |m, p| m.max(*p));
        assert!((hi.x * hi.y - 4.0).abs() < 1e-9, "{hi:?}");
    }
}
