//! Per-chart parameterisation: least-squares conformal maps (LSCM) solved by
//! Jacobi-preconditioned conjugate gradients, started from (and falling back to) the
//! orthographic projection onto the chart's mean-normal plane, plus the validity check
//! (no flipped triangles, no self-intersecting boundary).

use std::collections::HashMap;

use glam::{DVec2, DVec3};

use crate::charts::Surface;

/// A chart laid out in the plane (world units, before packing).
#[derive(Debug, Clone)]
pub(crate) struct ChartLayout {
    /// The chart's faces (input triangle indices).
    pub faces: Vec<u32>,
    /// Welded vertex of each local vertex.
    pub vertices: Vec<u32>,
    /// Faces over local vertices, in the order of `faces`.
    pub triangles: Vec<[u32; 3]>,
    /// Planar coordinates of each local vertex.
    pub uv: Vec<DVec2>,
}

/// Conjugate-gradient limits of [`lscm`].
const CG_MAX_ITERATIONS: usize = 200;
const CG_RELATIVE_TOLERANCE: f64 = 1e-6;

impl ChartLayout {
    /// Local indexing of a chart, with the projection onto its mean-normal plane.
    pub fn projected(surface: &Surface, faces: Vec<u32>) -> Self {
        let mut local: HashMap<u32, u32> = HashMap::with_capacity(faces.len());
        let mut vertices = Vec::new();
        let triangles: Vec<[u32; 3]> = faces
            .iter()
            .map(|&f| {
                surface.triangles[f as usize].map(|v| {
                    *local.entry(v).or_insert_with(|| {
                        vertices.push(v);
                        vertices.len() as u32 - 1
                    })
                })
            })
            .collect();
        let axis = faces
            .iter()
            .map(|&f| surface.normals[f as usize] * surface.areas[f as usize])
            .sum::<DVec3>()
            .normalize_or(DVec3::Z);
        let (t, b) = axis.any_orthonormal_pair();
        let uv = vertices
            .iter()
            .map(|&v| {
                let p = surface.positions[v as usize];
                DVec2::new(p.dot(t), p.dot(b))
            })
            .collect();
        ChartLayout { faces, vertices, triangles, uv }
    }

    /// Signed area of local triangle `i` in the layout.
    pub fn uv_area(&self, i: usize) -> f64 {
        let [a, b, c] = self.triangles[i].map(|v| self.uv[v as usize]);
        0.5 * (b - a).perp_dot(c - a)
    }

    /// Scales the layout uniformly so its area equals the chart's surface area and moves
    /// its bounding box to the origin.
    pub fn normalise_scale(&mut self, surface: &Surface) {
        let uv_area: f64 = (0..self.triangles.len()).map(|i| self.uv_area(i)).sum();
        let area: f64 = self.faces.iter().map(|&f| surface.areas[f as usize]).sum();
        let s = if uv_area > 0.0 && area > 0.0 { (area / uv_area).sqrt() } else { 1.0 };
        let lo = self.uv.iter().fold(DVec2::splat(f64::INFINITY), |m, p| m.min(*p));
        for p in &mut self.uv {
            *p = (*p - lo) * s;
        }
    }
}

/// The three corners of face `f` laid out in its own plane: `q0 = 0`, `q1` on +x,
/// `q2` above the x axis (counter-clockwise). `None` for a degenerate face.
fn local_triangle(surface: &Surface, f: u32) -> Option<[DVec2; 3]> {
    let [a, b, c] = surface.triangles[f as usize].map(|v| surface.positions[v as usize]);
    let e1 = b - a;
    let len = e1.length();
    let x = e1 / len;
    let d = c - a;
    let h = x.cross(d).length();
    (len > 0.0 && h > 0.0 && h.is_finite()).then(|| [DVec2::ZERO, DVec2::new(len, 0.0), DVec2::new(d.dot(x), h)])
}

/// Least-squares conformal map of a chart, started from `layout.uv` (the projection):
/// minimises `Σ_T A_T |∇v − ∇u^⊥|²` with the two vertices farthest apart along the
/// layout's wider axis pinned, by preconditioned conjugate gradients. Returns the new
/// coordinates (degenerate faces do not contribute).
pub(crate) fn lscm(surface: &Surface, layout: &ChartLayout) -> Vec<DVec2> {
    let n = layout.uv.len();
    // Two residual rows per face, each touching the 6 unknowns (u, v) of its corners:
    // r = 1/(2√A) · Σ_j (u_j e_j + v_j e_j^⊥), e_j = q_{j+2} − q_{j+1}.
    let mut rows: Vec<([usize; 3], [DVec2; 3])> = Vec::with_capacity(layout.triangles.len());
    let mut diag = vec![0.0f64; n];
    for (t, &f) in layout.triangles.iter().zip(&layout.faces) {
        let Some(q) = local_triangle(surface, f) else { continue };
        let area = 0.5 * (q[1] - q[0]).perp_dot(q[2] - q[0]);
        let w = 1.0 / (2.0 * area.sqrt());
        let e = [0, 1, 2].map(|j| (q[(j + 2) % 3] - q[(j + 1) % 3]) * w);
        for j in 0..3 {
            diag[t[j] as usize] += e[j].length_squared();
        }
        rows.push((t.map(|v| v as usize), e));
    }
    if rows.is_empty() || n < 3 {
        return layout.uv.clone();
    }
    // Pins: extreme vertices along the wider axis of the starting layout.
    let (lo, hi) = layout
        .uv
        .iter()
        .fold((DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY)), |(l, h), p| (l.min(*p), h.max(*p)));
    let axis = if hi.x - lo.x >= hi.y - lo.y { DVec2::X } else { DVec2::Y };
    let key = |i: &usize| layout.uv[*i].dot(axis);
    let pin_a = (0..n).min_by(|a, b| key(a).total_cmp(&key(b))).expect("non-empty");
    let pin_b = (0..n).max_by(|a, b| key(a).total_cmp(&key(b))).expect("non-empty");
    let mut free = vec![true; n];
    free[pin_a] = false;
    free[pin_b] = false;

    // y = Jᵀ J x on the (u, v) pairs, with pinned entries masked out of the result.
    let apply = |x: &[DVec2], y: &mut [DVec2]| {
        y.iter_mut().for_each(|v| *v = DVec2::ZERO);
        for (t, e) in &rows {
            let mut r = DVec2::ZERO;
            for j in 0..3 {
                let p = x[t[j]];
                r += e[j] * p.x + e[j].perp() * p.y;
            }
            for j in 0..3 {
                y[t[j]] += DVec2::new(e[j].dot(r), e[j].perp().dot(r));
            }
        }
        for (v, &f) in y.iter_mut().zip(&free) {
            if !f {
                *v = DVec2::ZERO;
            }
        }
    };
    let mut x = layout.uv.clone();
    let mut ax = vec![DVec2::ZERO; n];
    apply(&x, &mut ax);
    let mut r: Vec<DVec2> = ax.iter().map(|v| -*v).collect();
    let inv_diag: Vec<f64> = diag.iter().zip(&free).map(|(&d, &f)| if f && d > 0.0 { 1.0 / d } else { 0.0 }).collect();
    let mut z: Vec<DVec2> = r.iter().zip(&inv_diag).map(|(v, d)| *v * *d).collect();
    let mut p = z.clone();
    let dot = |a: &[DVec2], b: &[DVec2]| a.iter().zip(b).map(|(x, y)| x.dot(*y)).sum::<f64>();
    let mut rz = dot(&r, &z);
    let r0 = dot(&r, &r).sqrt();
    let mut ap = vec![DVec2::ZERO; n];
    for _ in 0..CG_MAX_ITERATIONS {
        if dot(&r, &r).sqrt() <= CG_RELATIVE_TOLERANCE * r0.max(1e-300) {
            break;
        }
        apply(&p, &mut ap);
        let pap = dot(&p, &ap);
        if pap <= 0.0 || !pap.is_finite() {
            break;
        }
        let alpha = rz / pap;
        for i in 0..n {
            x[i] += p[i] * alpha;
            r[i] -= ap[i] * alpha;
            z[i] = r[i] * inv_diag[i];
        }
        let rz_new = dot(&r, &z);
        let beta = rz_new / rz;
        rz = rz_new;
        for i in 0..n {
            p[i] = z[i] + p[i] * beta;
        }
    }
    x
}

/// True when every non-degenerate face of the layout keeps its orientation (positive
/// area) and no two boundary edges without a common vertex touch or cross.
pub(crate) fn is_valid(surface: &Surface, layout: &ChartLayout) -> bool {
    if layout.uv.iter().any(|p| !p.is_finite()) {
        return false;
    }
    let total: f64 = (0..layout.triangles.len()).map(|i| layout.uv_area(i).abs()).sum();
    let min_area = total * 1e-12;
    for (i, &f) in layout.faces.iter().enumerate() {
        if surface.areas[f as usize] > 0.0 && layout.uv_area(i) <= min_area {
            return false;
        }
    }
    // Boundary edges: directed edges whose reverse is not in the chart.
    let mut directed: HashMap<(u32, u32), u32> = HashMap::with_capacity(layout.triangles.len() * 3);
    for t in &layout.triangles {
        for k in 0..3 {
            *directed.entry((t[k], t[(k + 1) % 3])).or_insert(0) += 1;
        }
    }
    let boundary: Vec<[u32; 2]> = directed
        .iter()
        .filter(|&(&(a, b), &c)| c == 1 && !directed.contains_key(&(b, a)))
        .map(|(&(a, b), _)| [a, b])
        .collect();
    if boundary.len() < 4 {
        return true;
    }
    // Uniform grid over the boundary edges' boxes, cell = mean edge length.
    let seg = |e: &[u32; 2]| (layout.uv[e[0] as usize], layout.uv[e[1] as usize]);
    let mean = boundary.iter().map(|e| (seg(e).1 - seg(e).0).length()).sum::<f64>() / boundary.len() as f64;
    if mean <= 0.0 {
        return false;
    }
    let mut grid: HashMap<(i64, i64), Vec<u32>> = HashMap::new();
    for (i, e) in boundary.iter().enumerate() {
        let (a, b) = seg(e);
        let (lo, hi) = (a.min(b) / mean, a.max(b) / mean);
        for cx in lo.x.floor() as i64..=hi.x.floor() as i64 {
            for cy in lo.y.floor() as i64..=hi.y.floor() as i64 {
                grid.entry((cx, cy)).or_default().push(i as u32);
            }
        }
    }
    for cell in grid.values() {
        for (k, &i) in cell.iter().enumerate() {
            for &j in &cell[k + 1..] {
                let (e, g) = (boundary[i as usize], boundary[j as usize]);
                if e[0] == g[0] || e[0] == g[1] || e[1] == g[0] || e[1] == g[1] {
                    continue;
                }
                if segments_touch(seg(&e), seg(&g)) {
                    return false;
                }
            }
        }
    }
    true
}

/// Whether two closed segments share a point (floating point orientation tests).
fn segments_touch((a, b): (DVec2, DVec2), (c, d): (DVec2, DVec2)) -> bool {
    let o = |p: DVec2, q: DVec2, r: DVec2| (q - p).perp_dot(r - p);
    let (o1, o2, o3, o4) = (o(a, b, c), o(a, b, d), o(c, d, a), o(c, d, b));
    let on = |p: DVec2, q: DVec2, r: DVec2| {
        r.x >= p.x.min(q.x) && r.x <= p.x.max(q.x) && r.y >= p.y.min(q.y) && r.y <= p.y.max(q.y)
    };
    if o1 * o2 < 0.0 && o3 * o4 < 0.0 {
        return true;
    }
    (o1 == 0.0 && on(a, b, c)) || (o2 == 0.0 && on(a, b, d)) || (o3 == 0.0 && on(c, d, a)) || (o4 == 0.0 && on(c, d, b))
}

/// Angle distortion of a layout: `(Σ_T A_T · mean_corner |θ_uv − θ_3d|, Σ_T A_T)` in
/// radians × area, for aggregation over charts.
pub(crate) fn angle_distortion(surface: &Surface, layout: &ChartLayout) -> (f64, f64) {
    let angles2 = |p: [DVec2; 3]| [0, 1, 2].map(|k| (p[(k + 1) % 3] - p[k]).angle_to(p[(k + 2) % 3] - p[k]).abs());
    let mut sum = 0.0;
    let mut weight = 0.0;
    for (t, &f) in layout.triangles.iter().zip(&layout.faces) {
        let Some(q) = local_triangle(surface, f) else { continue };
        let a3 = angles2(q);
        let auv = angles2(t.map(|v| layout.uv[v as usize]));
        let area = surface.areas[f as usize];
        sum += area * (0..3).map(|k| (a3[k] - auv[k]).abs()).sum::<f64>() / 3.0;
        weight += area;
    }
    (sum, weight)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An `n × n` grid of quads on the paraboloid `z = c (x² + y²)` over `[-1, 1]²`.
    fn cap(n: usize, c: f64) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
        let mut p = Vec::new();
        for j in 0..=n {
            for i in 0..=n {
                let (x, y) = (2.0 * i as f64 / n as f64 - 1.0, 2.0 * j as f64 / n as f64 - 1.0);
                p.push([x as f32, y as f32, (c * (x * x + y * y)) as f32]);
            }
        }
        let mut t = Vec::new();
        let id = |i: usize, j: usize| (j * (n + 1) + i) as u32;
        for j in 0..n {
            for i in 0..n {
                t.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
                t.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
            }
        }
        (p, t)
    }

    fn distortion_deg(s: &Surface, l: &ChartLayout) -> f64 {
        let (sum, w) = angle_distortion(s, l);
        (sum / w).to_degrees()
    }

    #[test]
    fn flat_chart_is_isometric() {
        let (p, t) = cap(8, 0.0);
        let s = Surface::new(&p, &t);
        let mut layout = ChartLayout::projected(&s, (0..t.len() as u32).collect());
        layout.uv = lscm(&s, &layout);
        assert!(is_valid(&s, &layout));
        assert!(distortion_deg(&s, &layout) < 1e-6);
    }

    #[test]
    fn lscm_reduces_angle_distortion_of_a_curved_cap() {
        let (p, t) = cap(16, 0.6);
        let s = Surface::new(&p, &t);
        let mut layout = ChartLayout::projected(&s, (0..t.len() as u32).collect());
        let projected = distortion_deg(&s, &layout);
        layout.uv = lscm(&s, &layout);
        let conformal = distortion_deg(&s, &layout);
        assert!(is_valid(&s, &layout));
        assert!(conformal < 0.5 * projected, "projection {projected:.2}°, LSCM {conformal:.2}°");
        layout.normalise_scale(&s);
        let area: f64 = (0..layout.triangles.len()).map(|i| layout.uv_area(i)).sum();
        assert!((area - s.areas.iter().sum::<f64>()).abs() < 1e-9 * area);
    }

    #[test]
    fn flipped_and_overlapping_layouts_are_invalid() {
        let (p, t) = cap(4, 0.0);
        let s = Surface::new(&p, &t);
        let layout = ChartLayout::projected(&s, (0..t.len() as u32).collect());
        assert!(is_valid(&s, &layout));
        let mut mirrored = layout.clone();
        mirrored.uv.iter_mut().for_each(|q| q.x = -q.x);
        assert!(!is_valid(&s, &mirrored));
        // Wrap the grid more than once around a circle, keeping every face's orientation.
        let mut wrapped = layout.clone();
        for q in &mut wrapped.uv {
            let (r, a) = (2.0 - q.y, (q.x + 1.0) * 1.2 * std::f64::consts::PI);
            *q = DVec2::new(r * a.cos(), r * a.sin());
        }
        assert!(!is_valid(&s, &wrapped));
    }
}
