//! The robust kernel: Geman–McClure weights and their scale.
//!
//! Points of a partial scan that the target does not cover have large residuals; with least
//! squares they pull the pose off. Iteratively reweighted least squares with the Geman–McClure
//! kernel `ρ(r) = c² r² / (c² + r²)` (weight `w = (c² / (c² + r²))²`) lets them go: the SDF's LM
//! ([`crate::solve::lm`]) and the final polish both use [`Kernel::rho_weight`]. In the polish the
//! scale is [`SCALE_SIGMAS`] robust standard deviations ([`MAD_TO_SIGMA`] × median |r|),
//! re-estimated on the residuals under it until it settles (`inlier_scale`); when a
//! registration uses the kernel is the pipeline's choice (`pipeline::robust`).

/// Robust standard deviations in the polish's kernel scale.
pub const SCALE_SIGMAS: f64 = 3.0;

/// The median absolute deviation times this estimates a Gaussian's standard deviation.
pub const MAD_TO_SIGMA: f64 = 1.4826;

/// Residual kernel of the normal equations (iteratively reweighted least squares).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub enum Kernel {
    /// Plain least squares, `ρ(r) = r²`, weight 1.
    L2,
    /// Geman–McClure with scale `c` (same units as the residuals):
    /// `ρ(r) = c² r² / (c² + r²)`, weight `w = (c² / (c² + r²))²`.
    GemanMcClure(f64),
}

impl Kernel {
    /// The Geman–McClure scale; `None` for least squares.
    pub fn scale(&self) -> Option<f64> {
        match *self {
            Kernel::L2 => None,
            Kernel::GemanMcClure(c) => Some(c),
        }
    }

    /// `(ρ(r), w(r))`, with `ρ'(r) = 2 w r` (the IRLS weight).
    #[inline]
    pub fn rho_weight(&self, r: f64) -> (f64, f64) {
        match *self {
            Kernel::L2 => (r * r, 1.0),
            Kernel::GemanMcClure(c) => {
                let c2 = c * c;
                let q = c2 / (c2 + r * r);
                (r * r * q, q * q)
            }
        }
    }
}

/// The scale of [`SCALE_SIGMAS`] robust standard deviations of the sorted residual magnitudes
/// `abs` (their median times [`MAD_TO_SIGMA`]).
pub(crate) fn mad_scale(sorted_abs: &[f64]) -> f64 {
    SCALE_SIGMAS * MAD_TO_SIGMA * sorted_abs[sorted_abs.len() / 2]
}

/// [`mad_scale`] re-estimated on the residuals below the previous scale until it settles.
/// The plain median is inflated when half the source lies outside the target's coverage
/// (a partial scan's boundary points within the distance gate); the re-estimate is not.
pub(crate) fn inlier_scale(sorted_abs: &[f64]) -> f64 {
    let mut c = mad_scale(sorted_abs);
    for _ in 0..20 {
        let n = sorted_abs.partition_point(|&a| a < c);
        if n < 6 {
            break;
        }
        // The median of a Gaussian truncated at c is below the untruncated one: for c ≥ 3σ
        // by under 2 %, which the loop's fixed point absorbs.
        let next = mad_scale(&sorted_abs[..n]);
        if next >= c * 0.999 {
            break;
        }
        c = next;
    }
    c.max(1e-9)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weights_are_the_derivative_of_rho() {
        let k = Kernel::GemanMcClure(0.05);
        for r in [-0.2, -0.01, 0.0, 0.03, 0.4] {
            let h = 1e-6;
            let drho = (k.rho_weight(r + h).0 - k.rho_weight(r - h).0) / (2.0 * h);
            // IRLS: ρ'(r) = 2 w r.
            assert!((drho - 2.0 * k.rho_weight(r).1 * r).abs() < 1e-6, "r = {r}");
        }
    }

    #[test]
    fn inlier_scale_ignores_a_far_half() {
        // Half the residuals ~ 1e-3, half spread far out: the median scale is inflated, the
        // re-estimate comes back to a few times 1e-3.
        let mut abs: Vec<f64> = (0..500).map(|i| 1e-3 * (i as f64 / 500.0)).collect();
        abs.extend((0..500).map(|i| 0.01 + 0.19 * i as f64 / 500.0));
        abs.sort_by(f64::total_cmp);
        assert!(mad_scale(&abs) > 0.04);
        let c = inlier_scale(&abs);
        assert!(c < 0.005, "{c}");
    }
}
