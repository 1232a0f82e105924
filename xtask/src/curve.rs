//! Reading the uniform remeshing's (triangles, CD) curve of `cargo xtask faces-chart`. A module
//! without dependencies on the rest of xtask, so that `tests/curve.rs` can compile it into a
//! test harness: the xtask binary has none (`test = false` in `Cargo.toml`).

/// Triangles the uniform curve needs to reach `cd`: `Ok(n)` interpolated between the two
/// uniform points that bracket it, `Err(true)` when even the finest uniform mesh stays above
/// it, `Err(false)` when the coarsest is already below it.
pub(crate) fn uniform_triangles_at(uniform: &[(f64, f64)], cd: f64) -> Result<f64, bool> {
    // `uniform`: (triangles, CD), coarse to fine.
    if uniform.first().is_some_and(|&(_, c)| c <= cd) {
        return Err(false);
    }
    for w in uniform.windows(2) {
        let ((n0, c0), (n1, c1)) = (w[0], w[1]);
        if c1 <= cd && c0 > cd {
            let t = (c0 - cd) / (c0 - c1);
            return Ok((n0.ln() + t * (n1.ln() - n0.ln())).exp());
        }
    }
    Err(true)
}

#[cfg(test)]
mod tests {
    use super::uniform_triangles_at;

    #[test]
    fn uniform_triangles_interpolate_in_log_space() {
        let curve = [(1000.0, 0.004), (4000.0, 0.002)];
        let n = uniform_triangles_at(&curve, 0.003).unwrap();
        assert!((n - 2000.0).abs() < 1e-6, "{n}");
        assert_eq!(uniform_triangles_at(&curve, 0.001), Err(true));
        assert_eq!(uniform_triangles_at(&curve, 0.005), Err(false));
    }
}
