//! Surface distances between two sampled point sets: Chamfer distance, F-score and
//! normal consistency, from nearest neighbours found with `kiddo` k-d trees.

use glam::Vec3;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use rayon::prelude::*;
use w3d_core::{Error, Result};

use crate::sampling::SurfaceSamples;

/// Precision, recall and F-score at one distance threshold τ.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
#[non_exhaustive]
pub struct FScore {
    /// Fraction of predicted points within τ of the ground truth.
    pub precision: f64,
    /// Fraction of ground-truth points within τ of the prediction.
    pub recall: f64,
    /// Harmonic mean `2PR / (P + R)` (0 when both are 0).
    pub fscore: f64,
}

/// Nearest-neighbour distances in both directions between predicted and ground-truth
/// surface samples, plus the normal agreement at those pairs. Distances are Euclidean
/// (not squared), in the units of the samples.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub struct SurfaceComparison {
    /// For each predicted point, the distance to the nearest ground-truth point.
    pub pred_to_gt: Vec<f32>,
    /// For each ground-truth point, the distance to the nearest predicted point.
    pub gt_to_pred: Vec<f32>,
    /// `(mean |n_pred · n_gt| over pred→gt pairs + the same over gt→pred pairs) / 2`.
    pub normal_consistency: f64,
}

/// For each point of `from`: the distance to and the index of its nearest point in `to`.
pub(crate) fn nearest(from: &[[f32; 3]], to: &[[f32; 3]]) -> Vec<(f32, usize)> {
    let tree: ImmutableKdTree<f32, 3> = ImmutableKdTree::new_from_slice(to);
    from.par_iter()
        .map(|q| {
            let n = tree.nearest_one::<SquaredEuclidean>(q);
            (n.distance.max(0.0).sqrt(), n.item as usize)
        })
        .collect()
}

fn mean(values: impl Iterator<Item = f64>, len: usize) -> f64 {
    values.sum::<f64>() / len as f64
}

fn check_samples(field: &str, s: &SurfaceSamples) -> Result<()> {
    if s.points.is_empty() {
        return Err(Error::invalid(field, "at least one sample point, got none"));
    }
    if s.normals.len() != s.points.len() {
        return Err(Error::invalid(
            format!("{field}.normals"),
            format!("one normal per point ({}), got {}", s.points.len(), s.normals.len()),
        ));
    }
    if let Some(i) = s.points.iter().position(|p| !p.iter().all(|v| v.is_finite())) {
        return Err(Error::invalid(format!("{field}.points[{i}]"), "finite coordinates"));
    }
    Ok(())
}

impl SurfaceComparison {
    /// Finds nearest neighbours both ways between `pred` and `gt` (exact k-d tree
    /// queries, in parallel). Errors on an empty or non-finite sample set.
    pub fn new(pred: &SurfaceSamples, gt: &SurfaceSamples) -> Result<Self> {
        check_samples("pred samples", pred)?;
        check_samples("gt samples", gt)?;
        let p2g = nearest(&pred.points, &gt.points);
        let g2p = nearest(&gt.points, &pred.points);
        let cos = |a: [f32; 3], b: [f32; 3]| f64::from(Vec3::from(a).dot(Vec3::from(b)).abs());
        let nc_pred = mean(p2g.iter().enumerate().map(|(i, &(_, j))| cos(pred.normals[i], gt.normals[j])), p2g.len());
        let nc_gt = mean(g2p.iter().enumerate().map(|(i, &(_, j))| cos(gt.normals[i], pred.normals[j])), g2p.len());
        Ok(SurfaceComparison {
            pred_to_gt: p2g.into_iter().map(|(d, _)| d).collect(),
            gt_to_pred: g2p.into_iter().map(|(d, _)| d).collect(),
            normal_consistency: 0.5 * (nc_pred + nc_gt),
        })
    }

    /// Mean distance from predicted points to the ground truth ("accuracy").
    pub fn mean_pred_to_gt(&self) -> f64 {
        mean(self.pred_to_gt.iter().map(|&d| f64::from(d)), self.pred_to_gt.len())
    }

    /// Mean distance from ground-truth points to the prediction ("completeness").
    pub fn mean_gt_to_pred(&self) -> f64 {
        mean(self.gt_to_pred.iter().map(|&d| f64::from(d)), self.gt_to_pred.len())
    }

    /// Chamfer distance `(mean d_pred→gt + mean d_gt→pred) / 2`, Euclidean, not squared
    /// (the SyncDreamer / Wonder3D convention; point-cloud-utils reports twice this).
    pub fn chamfer(&self) -> f64 {
        0.5 * (self.mean_pred_to_gt() + self.mean_gt_to_pred())
    }

    /// Precision, recall and F-score at threshold `tau` (a point counts when its distance
    /// is `< tau`). Errors unless `tau` is positive and finite.
    pub fn fscore(&self, tau: f64) -> Result<FScore> {
        if !(tau > 0.0 && tau.is_finite()) {
            return Err(Error::invalid("fscore threshold", format!("a positive distance, got {tau}")));
        }
        let within = |d: &[f32]| d.iter().filter(|&&v| f64::from(v) < tau).count() as f64 / d.len() as f64;
        let (precision, recall) = (within(&self.pred_to_gt), within(&self.gt_to_pred));
        let fscore = if precision + recall > 0.0 { 2.0 * precision * recall / (precision + recall) } else { 0.0 };
        Ok(FScore { precision, recall, fscore })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn samples(points: Vec<[f32; 3]>, normal: [f32; 3]) -> SurfaceSamples {
        let normals = vec![normal; points.len()];
        SurfaceSamples { points, normals }
    }

    #[test]
    fn hand_computed_chamfer_and_fscore() {
        // pred: 0 and 3 on the x axis; gt: 0, 1 and 2.
        let pred = samples(vec![[0.0; 3], [3.0, 0.0, 0.0]], [0.0, 0.0, 1.0]);
        let gt = samples(vec![[0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]], [0.0, 0.6, 0.8]);
        let c = SurfaceComparison::new(&pred, &gt).unwrap();
        assert_eq!(c.pred_to_gt, vec![0.0, 1.0]);
        assert_eq!(c.gt_to_pred, vec![0.0, 1.0, 1.0]);
        assert!((c.chamfer() - 0.5 * (0.5 + 2.0 / 3.0)).abs() < 1e-12);
        let f = c.fscore(0.5).unwrap();
        assert_eq!((f.precision, f.recall), (0.5, 1.0 / 3.0));
        assert!((f.fscore - 0.4).abs() < 1e-12);
        assert!((c.normal_consistency - 0.8).abs() < 1e-6);
        assert!(c.fscore(0.0).is_err() && c.fscore(f64::NAN).is_err());
    }

    #[test]
    fn empty_or_mismatched_samples_are_errors() {
        let good = samples(vec![[0.0; 3]], [0.0, 0.0, 1.0]);
        let empty = samples(vec![], [0.0, 0.0, 1.0]);
        assert!(SurfaceComparison::new(&empty, &good).unwrap_err().to_string().contains("pred samples"));
        let bad = SurfaceSamples { points: vec![[0.0; 3]; 2], normals: vec![[0.0; 3]] };
        assert!(SurfaceComparison::new(&good, &bad).unwrap_err().to_string().contains("gt samples.normals"));
    }
}
