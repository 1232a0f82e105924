//! Small helpers shared by the unit tests.

use glam::DVec3;

/// A tiny deterministic generator of values in `[-1, 1)`.
pub(crate) struct Lcg(pub u64);

impl Lcg {
    pub(crate) fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((self.0 >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    }
}

/// `‖analytic − numeric‖ / ‖numeric‖` over all components (norm-wise relative error).
pub(crate) fn relative_error(analytic: &[[f32; 3]], numeric: &[[f64; 3]]) -> f64 {
    let (mut diff, mut norm) = (0.0, 0.0);
    for (a, n) in analytic.iter().zip(numeric) {
        let a = DVec3::new(a[0] as f64, a[1] as f64, a[2] as f64);
        let n = DVec3::from(*n);
        diff += (a - n).length_squared();
        norm += n.length_squared();
    }
    assert!(norm > 0.0, "the numeric gradient is zero: the check would be vacuous");
    (diff / norm).sqrt()
}
