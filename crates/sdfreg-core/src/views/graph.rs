//! The pose graph of many views: nodes are scan poses (scan → anchor frame), edges pairwise
//! registrations, solved by Gauss–Newton on SE(3).
//!
//! Edge `(i, j)` measures `Z`, the pose mapping scan `j` into scan `i`. Its residual is the left
//! error in scan `i`'s frame, `e = log(Tᵢ⁻¹ Tⱼ Z⁻¹)` (twist `[ω; v]`, [`crate::geometry::se3`]),
//! weighted by the registration's information `Ω` (its `JᵀJ` about scan `i`'s origin, divided by
//! its inlier RMSE²): the same left perturbation of `Z`. With left updates `T ← exp(δ) T`, to
//! first order `∂e/∂δⱼ = Ad(Tᵢ⁻¹)` and `∂e/∂δᵢ = −Ad(Tᵢ⁻¹)`. The anchor is fixed.
//!
//! **Why our own solver**: a graph of 100 views is 600 unknowns; a dense Cholesky of that size
//! takes milliseconds, and the solver is the se(3) exp/log maps the registration already uses plus
//! forty lines. The Rust factor-graph crates would add a dependency (and their own pose types)
//! for no gain at this size.

use nalgebra::{DMatrix, DVector, Isometry3, Matrix6, Vector6};

pub use crate::geometry::se3::adjoint;
use crate::geometry::se3::{exp_se3, log_se3};

/// One relative measurement.
#[derive(Clone, Debug)]
pub struct GraphEdge {
    /// The scan whose frame `z` maps into.
    pub i: usize,
    /// The scan `z` maps from.
    pub j: usize,
    /// `Tᵢ⁻¹ Tⱼ` as measured.
    pub z: Isometry3<f64>,
    /// The information of the left error in scan `i`'s frame.
    pub information: Matrix6<f64>,
}

/// The edge's residual at `poses`.
pub fn residual(e: &GraphEdge, poses: &[Isometry3<f64>]) -> Vector6<f64> {
    log_se3(&(poses[e.i].inverse() * poses[e.j] * e.z.inverse()))
}

/// `Σ eᵀ Ω e` over `edges` at `poses`.
pub fn cost(edges: &[GraphEdge], poses: &[Isometry3<f64>]) -> f64 {
    edges
        .iter()
        .map(|e| {
            let r = residual(e, poses);
            (r.transpose() * e.information * r)[0]
        })
        .sum()
}

/// Gauss–Newton from `poses` (every node's, the `anchor` held fixed) over `edges`, at most
/// `iterations` steps, each taken only when it lowers the cost; returns the iterations run.
pub fn optimise(
    edges: &[GraphEdge],
    poses: &mut [Isometry3<f64>],
    anchor: usize,
    iterations: usize,
) -> usize {
    let n = poses.len();
    // Unknowns: every node but the anchor, 6 each.
    let slot = |k: usize| (k != anchor).then(|| 6 * (k - usize::from(k > anchor)));
    let mut current = cost(edges, poses);
    for it in 0..iterations {
        let mut h = DMatrix::<f64>::zeros(6 * (n - 1), 6 * (n - 1));
        let mut b = DVector::<f64>::zeros(6 * (n - 1));
        for e in edges {
            let r = residual(e, poses);
            let a = adjoint(&poses[e.i].inverse());
            let blocks = [(e.j, a), (e.i, -a)];
            for (k, jk) in &blocks {
                let Some(sk) = slot(*k) else { continue };
                let g = jk.transpose() * e.information * r;
                let mut rows = b.rows_mut(sk, 6);
                rows += g;
                for (l, jl) in &blocks {
                    let Some(sl) = slot(*l) else { continue };
                    let block = jk.transpose() * e.information * jl;
                    let mut view = h.view_mut((sk, sl), (6, 6));
                    view += block;
                }
            }
        }
        for d in 0..h.nrows() {
            h[(d, d)] += 1e-9 * h[(d, d)].abs().max(1e-9);
        }
        let Some(chol) = h.cholesky() else {
            return it;
        };
        let delta = chol.solve(&(-b));
        let moved: Vec<Isometry3<f64>> = (0..n)
            .map(|k| match slot(k) {
                Some(s) => {
                    exp_se3(&Vector6::from_iterator(delta.rows(s, 6).iter().copied())) * poses[k]
                }
                None => poses[k],
            })
            .collect();
        let next = cost(edges, &moved);
        if next.partial_cmp(&current) != Some(std::cmp::Ordering::Less) {
            return it + 1;
        }
        poses.copy_from_slice(&moved);
        let small = delta.amax() < 1e-10;
        current = next;
        if small {
            return it + 1;
        }
    }
    iterations
}

/// [`optimise`] with Cauchy weights on the edges, re-estimated `rounds` times: an edge whose
/// `eᵀΩe` is `c²` times the median counts `1/(1 + c²)` (a registration that kept a small
/// error with much confidence — a slide along a wall, a near-symmetric view — does not pull the
/// others). Returns the edges' final weights.
pub fn optimise_robust(
    edges: &[GraphEdge],
    poses: &mut [Isometry3<f64>],
    anchor: usize,
    iterations: usize,
    rounds: usize,
) -> Vec<f64> {
    let mut weights = vec![1.0; edges.len()];
    for _ in 0..rounds.max(1) {
        let weighted: Vec<GraphEdge> = edges
            .iter()
            .zip(&weights)
            .map(|(e, w)| GraphEdge {
                information: e.information * *w,
                ..e.clone()
            })
            .collect();
        optimise(&weighted, poses, anchor, iterations);
        let chi2: Vec<f64> = edges
            .iter()
            .map(|e| {
                let r = residual(e, poses);
                (r.transpose() * e.information * r)[0]
            })
            .collect();
        let mut sorted = chi2.clone();
        sorted.sort_by(f64::total_cmp);
        let median = sorted
            .get(sorted.len() / 2)
            .copied()
            .unwrap_or(1.0)
            .max(1e-12);
        weights = chi2.iter().map(|c| 1.0 / (1.0 + c / median)).collect();
    }
    weights
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose(k: f64) -> Isometry3<f64> {
        exp_se3(&Vector6::new(0.1 * k, -0.05 * k, 0.2, k, 0.5 * k, -0.2 * k))
    }

    #[test]
    fn a_loop_with_noisy_edges_closes_and_a_perturbed_graph_returns() {
        // Five poses in a loop; every edge measured exactly, the starting poses perturbed.
        let truth: Vec<Isometry3<f64>> = (0..5).map(|k| pose(k as f64)).collect();
        let mut edges = Vec::new();
        for i in 0..5 {
            let j = (i + 1) % 5;
            edges.push(GraphEdge {
                i,
                j,
                z: truth[i].inverse() * truth[j],
                information: Matrix6::identity(),
            });
        }
        let mut poses: Vec<Isometry3<f64>> = truth
            .iter()
            .enumerate()
            .map(|(k, t)| {
                if k == 0 {
                    *t
                } else {
                    exp_se3(&Vector6::new(0.02, -0.01, 0.03, 0.05, -0.02, 0.04)) * t
                }
            })
            .collect();
        optimise(&edges, &mut poses, 0, 20);
        for (p, t) in poses.iter().zip(&truth) {
            assert!((p.to_homogeneous() - t.to_homogeneous()).amax() < 1e-8);
        }
    }
}
