//! Rigid motions: the SO(3) and SE(3) exponential and logarithm maps.
//!
//! **Twist order** (used everywhere in sdfreg): a twist `ξ = [ω; v]` is a 6-vector with the
//! rotation part `ω` (axis × angle, radians) first and the translation part `v` second.
//! Poses are [`Isometry3<f64>`] values; an update `δ` is applied on the **left**,
//! `T ← exp(δ^) · T`, i.e. in the frame the pose maps into (the target frame during
//! registration). This is the paper's eq. 13.
//!
//! Entry points: [`hat`], [`vee`], [`exp_so3`], [`log_so3`], [`exp_se3`], [`log_se3`],
//! [`adjoint`],
//! [`rotation_angle`] (geodesic distance between rotations), [`isometry_from_matrix`] (a user's
//! 4×4 matrix checked to be rigid), [`matrix_rows`] (a matrix as JSON's nested rows) and
//! [`matrix_from_rows`] (a 4×4 read back from them).

use nalgebra::{
    Isometry3, Matrix3, Matrix4, Matrix6, Rotation3, SMatrix, SVector, Translation3,
    UnitQuaternion, Vector3, Vector6,
};

/// How far a user's 3×3 block may be from a rotation (`|RᵀR − I|` entries, `|det R − 1|`), and
/// the last row from `[0 0 0 1]`, for [`isometry_from_matrix`].
pub const RIGID_TOLERANCE: f64 = 1e-3;

/// The rigid motion of a homogeneous 4×4 matrix `[R t; 0 1]`, or `None` when an entry is not
/// finite, `R` is not a rotation within [`RIGID_TOLERANCE`] or the last row is not `[0 0 0 1]`.
/// `R` is re-orthonormalised (the nearest rotation), so values printed with few digits work.
pub fn isometry_from_matrix(m: &Matrix4<f64>) -> Option<Isometry3<f64>> {
    let r: Matrix3<f64> = m.fixed_view::<3, 3>(0, 0).into();
    let last = [m[(3, 0)], m[(3, 1)], m[(3, 2)], m[(3, 3)] - 1.0];
    if !m.iter().all(|v| v.is_finite())
        || (r.transpose() * r - Matrix3::identity()).amax() > RIGID_TOLERANCE
        || (r.determinant() - 1.0).abs() > RIGID_TOLERANCE
        || last.iter().any(|v| v.abs() > RIGID_TOLERANCE)
    {
        return None;
    }
    let rot = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix(&r));
    Some(Isometry3::from_parts(
        Translation3::new(m[(0, 3)], m[(1, 3)], m[(2, 3)]),
        rot,
    ))
}

/// A matrix as a list of rows (row-major nested lists in JSON: the 4×4 transformations and
/// 6×6 information matrices of the CLI's and the poses file's JSON).
pub fn matrix_rows<const R: usize, const C: usize>(m: &SMatrix<f64, R, C>) -> Vec<[f64; C]> {
    (0..R).map(|r| std::array::from_fn(|c| m[(r, c)])).collect()
}

/// A 4×4 read back from JSON's four rows of four numbers ([`matrix_rows`]' inverse: the
/// `transformation` of `register --output`'s JSON and of a poses file); `None` when `v` is not
/// that.
pub fn matrix_from_rows(v: &serde_json::Value) -> Option<Matrix4<f64>> {
    let rows = v.as_array().filter(|r| r.len() == 4)?;
    let mut m = Matrix4::zeros();
    for (r, row) in rows.iter().enumerate() {
        let row = row.as_array().filter(|c| c.len() == 4)?;
        for (c, x) in row.iter().enumerate() {
            m[(r, c)] = x.as_f64()?;
        }
    }
    Some(m)
}

/// The similarity of a homogeneous 4×4 matrix `[s R t; 0 1]` (`s > 0`): its rigid part
/// (`R`, `t`) and `s`, the cube root of the 3×3 block's determinant; `None` when that is not
/// positive or the block divided by it is not a rotation (see [`isometry_from_matrix`]).
pub fn similarity_from_matrix(m: &Matrix4<f64>) -> Option<(Isometry3<f64>, f64)> {
    let det = m.fixed_view::<3, 3>(0, 0).determinant();
    if !det.is_finite() || det <= 0.0 {
        return None;
    }
    let s = det.cbrt();
    let mut unscaled = *m;
    unscaled.fixed_view_mut::<3, 3>(0, 0).unscale_mut(s);
    Some((isometry_from_matrix(&unscaled)?, s))
}

/// Below this angle (radians) the maps use Taylor expansions instead of the closed forms.
const SMALL_ANGLE: f64 = 1e-5;
/// Within this distance of π (radians) the SO(3) log uses the symmetric-part formula.
const NEAR_PI: f64 = 1e-3;

/// The skew-symmetric matrix `[w]×` with `[w]× x = w × x`.
pub fn hat(w: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -w.z, w.y, w.z, 0.0, -w.x, -w.y, w.x, 0.0)
}

/// Inverse of [`hat`]: reads `w` from the skew part of `m` (its symmetric part is ignored).
pub fn vee(m: &Matrix3<f64>) -> Vector3<f64> {
    0.5 * Vector3::new(
        m[(2, 1)] - m[(1, 2)],
        m[(0, 2)] - m[(2, 0)],
        m[(1, 0)] - m[(0, 1)],
    )
}

/// Rodrigues' formula: the rotation by angle `|w|` (radians) about `w/|w|`.
pub fn exp_so3(w: &Vector3<f64>) -> Rotation3<f64> {
    let theta2 = w.norm_squared();
    let theta = theta2.sqrt();
    let k = hat(w);
    let (a, b) = if theta < SMALL_ANGLE {
        (1.0 - theta2 / 6.0, 0.5 - theta2 / 24.0)
    } else {
        (theta.sin() / theta, (1.0 - theta.cos()) / theta2)
    };
    let m = Matrix3::identity() + a * k + b * k * k;
    Rotation3::from_matrix_unchecked(m)
}

/// The rotation vector `w` (radians, `|w| ≤ π`) with `exp_so3(w) = r`.
pub fn log_so3(r: &Rotation3<f64>) -> Vector3<f64> {
    let m = r.matrix();
    let cos = ((m.trace() - 1.0) * 0.5).clamp(-1.0, 1.0);
    let theta = cos.acos();
    let skew = vee(m);
    if theta < SMALL_ANGLE {
        // sin θ / θ ≈ 1 − θ²/6: first-order accurate skew part.
        return skew * (1.0 + theta * theta / 6.0);
    }
    if std::f64::consts::PI - theta > NEAR_PI {
        return skew * (theta / theta.sin());
    }
    // Near π the skew part vanishes; read the axis from R + Rᵀ = 2cosθ I + 2(1−cosθ) aaᵀ.
    let s = (m + m.transpose()) * 0.5 - Matrix3::identity() * cos;
    let denom = 1.0 - cos;
    let diag = Vector3::new(s[(0, 0)], s[(1, 1)], s[(2, 2)]) / denom;
    // Take the largest component for numerical stability, then the others from off-diagonals.
    let i = diag.imax();
    let mut axis = Vector3::zeros();
    axis[i] = diag[i].max(0.0).sqrt();
    for j in 0..3 {
        if j != i {
            axis[j] = s[(i, j)] / denom / axis[i];
        }
    }
    axis.normalize_mut();
    // Fix the sign with the (small) skew part so exp(log(R)) = R also for θ slightly below π.
    if axis.dot(&skew) < 0.0 {
        axis = -axis;
    }
    axis * theta
}

/// `V(w)`, the left Jacobian of SO(3): the translation of `exp_se3([w; v])` is `V(w) v`.
fn left_jacobian(w: &Vector3<f64>) -> Matrix3<f64> {
    let theta2 = w.norm_squared();
    let theta = theta2.sqrt();
    let k = hat(w);
    let (b, c) = if theta < SMALL_ANGLE {
        (0.5 - theta2 / 24.0, 1.0 / 6.0 - theta2 / 120.0)
    } else {
        (
            (1.0 - theta.cos()) / theta2,
            (theta - theta.sin()) / (theta2 * theta),
        )
    };
    Matrix3::identity() + b * k + c * k * k
}

/// The adjoint of `t` on twists `[ω; v]`: `exp(Ad(t) ξ) = t exp(ξ) t⁻¹`, so a left
/// perturbation of `t⁻¹` is a left perturbation of `t` by `−Ad(t) ξ`
/// (`exp(ξ) t⁻¹ = (exp(−Ad(t) ξ) t)⁻¹`). `Ad(t) = [[R, 0], [[t]ₓ R, R]]`.
pub fn adjoint(t: &Isometry3<f64>) -> Matrix6<f64> {
    let r: Matrix3<f64> = t.rotation.to_rotation_matrix().into_inner();
    let mut a = Matrix6::zeros();
    a.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    a.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
    a.fixed_view_mut::<3, 3>(3, 0)
        .copy_from(&(hat(&t.translation.vector) * r));
    a
}

/// The rigid motion `exp(ξ^)` of a twist `ξ = [ω; v]` (radians; length units of `v`).
pub fn exp_se3(xi: &Vector6<f64>) -> Isometry3<f64> {
    let w = Vector3::new(xi[0], xi[1], xi[2]);
    let v = Vector3::new(xi[3], xi[4], xi[5]);
    let r = exp_so3(&w);
    let t = left_jacobian(&w) * v;
    Isometry3::from_parts(
        Translation3::from(t),
        UnitQuaternion::from_rotation_matrix(&r),
    )
}

/// A left step `δ = [ω; v; σ]` of a similarity `x = T (s p)`: `x ↦ e^σ exp([ω; v]^) x`, with
/// the new scale kept within `[min, max]` (the step's σ shortened to the bound). Returns the new
/// rigid part and scale.
pub fn similarity_step(
    delta: &SVector<f64, 7>,
    pose: &Isometry3<f64>,
    s: f64,
    (min, max): (f64, f64),
) -> (Isometry3<f64>, f64) {
    let rigid = exp_se3(&delta.fixed_rows::<6>(0).into_owned()) * pose;
    let scaled = (s * delta[6].exp()).clamp(min, max);
    let e = scaled / s;
    let moved = Isometry3::from_parts(
        Translation3::from(rigid.translation.vector * e),
        rigid.rotation,
    );
    (moved, scaled)
}

/// The twist `ξ = [ω; v]` with `exp_se3(ξ) = T` and `|ω| ≤ π`.
pub fn log_se3(t: &Isometry3<f64>) -> Vector6<f64> {
    let w = log_so3(&t.rotation.to_rotation_matrix());
    // V(w) is invertible for |w| < 2π; solve rather than form the closed-form inverse.
    let v = left_jacobian(&w)
        .lu()
        .solve(&t.translation.vector)
        .unwrap_or(t.translation.vector);
    Vector6::new(w.x, w.y, w.z, v.x, v.y, v.z)
}

/// Rotation error (geodesic, degrees) and translation error (Euclidean, the poses' units) of
/// `estimate` against `truth`.
pub fn pose_errors(estimate: &Isometry3<f64>, truth: &Isometry3<f64>) -> (f64, f64) {
    let r = rotation_angle(
        &estimate.rotation.to_rotation_matrix(),
        &truth.rotation.to_rotation_matrix(),
    )
    .to_degrees();
    let t = (estimate.translation.vector - truth.translation.vector).norm();
    (r, t)
}

/// Geodesic angle (radians, in `[0, π]`) of the relative rotation `m = aᵀ b`:
/// `atan2(‖vee(m − mᵀ)‖, tr m − 1)` (`= atan2(2 sin θ, 2 cos θ)`), exact to rounding at every
/// angle, where `acos((tr m − 1) / 2)` resolves only ~1e-8 rad near 0.
pub fn rotation_angle(a: &Rotation3<f64>, b: &Rotation3<f64>) -> f64 {
    let m = a.matrix().transpose() * b.matrix();
    let twice_sin = Vector3::new(
        m[(2, 1)] - m[(1, 2)],
        m[(0, 2)] - m[(2, 0)],
        m[(1, 0)] - m[(0, 1)],
    )
    .norm();
    twice_sin.atan2(m.trace() - 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    #[test]
    fn the_adjoint_moves_a_twist_between_frames() {
        let t = exp_se3(&Vector6::new(0.13, -0.065, 0.2, 1.3, 0.65, -0.26));
        let xi = Vector6::new(0.01, -0.02, 0.015, 0.03, 0.0, -0.01);
        let lhs = exp_se3(&(adjoint(&t) * xi));
        let rhs = t * exp_se3(&xi) * t.inverse();
        assert!((lhs.to_homogeneous() - rhs.to_homogeneous()).amax() < 1e-12);
        // A left perturbation of the inverse is one of `t` by −Ad(t) ξ.
        let of_inverse = exp_se3(&xi) * t.inverse();
        let via = (exp_se3(&-(adjoint(&t) * xi)) * t).inverse();
        assert!((of_inverse.to_homogeneous() - via.to_homogeneous()).amax() < 1e-12);
    }

    #[test]
    fn a_similarity_matrix_splits_into_its_rigid_part_and_scale() {
        let t = exp_se3(&Vector6::new(0.3, -0.2, 0.9, 1.0, 2.0, -3.0));
        let mut m = t.to_homogeneous();
        m.fixed_view_mut::<3, 3>(0, 0).scale_mut(0.002);
        let (rigid, s) = similarity_from_matrix(&m).unwrap();
        assert!((s - 0.002).abs() < 1e-15);
        assert!((rigid.to_homogeneous() - t.to_homogeneous()).amax() < 1e-9);
        // A reflection (negative determinant) and a shear are not similarities.
        let mut mirror = m;
        mirror.fixed_view_mut::<3, 1>(0, 0).neg_mut();
        assert!(similarity_from_matrix(&mirror).is_none());
        let mut shear = m;
        shear[(0, 1)] += 0.001;
        assert!(similarity_from_matrix(&shear).is_none());
    }

    fn vectors() -> Vec<Vector3<f64>> {
        let axes = [
            Vector3::new(1.0, 0.0, 0.0),
            Vector3::new(0.3, -0.8, 0.5).normalize(),
            Vector3::new(-0.2, 0.1, 0.97).normalize(),
        ];
        let angles = [
            0.0,
            1e-9,
            1e-6,
            1e-3,
            0.5,
            2.0,
            PI - 1e-2,
            PI - 1e-4,
            PI - 1e-7,
            PI,
        ];
        axes.iter()
            .flat_map(|a| angles.iter().map(move |t| a * *t))
            .collect()
    }

    #[test]
    fn the_rotation_angle_is_exact_from_0_to_pi() {
        for theta in [1e-12, 1e-9, 1e-6, 0.3, 1.0, 2.0, PI - 1e-6, PI] {
            let axis = Vector3::new(0.3, -0.5, 0.81).normalize();
            let a = Rotation3::from_axis_angle(
                &nalgebra::Unit::new_normalize(Vector3::new(1.0, 2.0, -0.5)),
                0.7,
            );
            let b = a * Rotation3::from_axis_angle(&nalgebra::Unit::new_normalize(axis), theta);
            let got = rotation_angle(&a, &b);
            assert!(
                (got - theta).abs() <= 1e-15 + 1e-9 * theta,
                "θ = {theta}: read {got}"
            );
        }
    }

    #[test]
    fn so3_round_trip_including_near_singular_angles() {
        for w in vectors() {
            let r = exp_so3(&w);
            // Orthonormal with determinant 1.
            let m = r.matrix();
            assert!((m.transpose() * m - Matrix3::identity()).norm() < 1e-12);
            assert!((m.determinant() - 1.0).abs() < 1e-12);
            let back = exp_so3(&log_so3(&r));
            let err = rotation_angle(&r, &back);
            assert!(err < 1e-7, "w = {w:?}: exp(log(R)) off by {err} rad");
            let theta = w.norm();
            if theta < PI - 1e-3 {
                assert!((log_so3(&r) - w).norm() < 1e-9 * (1.0 + theta), "w = {w:?}");
            }
        }
    }

    #[test]
    fn exp_so3_matches_nalgebra_axis_angle() {
        for w in vectors() {
            let ours = exp_so3(&w);
            let theirs = Rotation3::from_scaled_axis(w);
            assert!(
                (ours.matrix() - theirs.matrix()).norm() < 1e-12,
                "w = {w:?}"
            );
        }
    }

    #[test]
    fn se3_round_trip_and_composition() {
        let vs = [
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(0.4, -1.2, 2.5),
            Vector3::new(-3.0, 0.1, 0.01),
        ];
        for w in vectors() {
            for v in vs {
                let xi = Vector6::new(w.x, w.y, w.z, v.x, v.y, v.z);
                let t = exp_se3(&xi);
                let back = exp_se3(&log_se3(&t));
                assert!(
                    rotation_angle(
                        &t.rotation.to_rotation_matrix(),
                        &back.rotation.to_rotation_matrix()
                    ) < 1e-7
                );
                assert!(
                    (t.translation.vector - back.translation.vector).norm() < 1e-6,
                    "xi = {xi:?}"
                );
            }
        }
        // Twists along one axis commute: exp(a ξ) exp(b ξ) = exp((a + b) ξ).
        let xi = Vector6::new(0.3, -0.2, 0.5, 1.0, 2.0, -0.5);
        let lhs = exp_se3(&(xi * 0.4)) * exp_se3(&(xi * 0.9));
        let rhs = exp_se3(&(xi * 1.3));
        assert!((lhs.to_homogeneous() - rhs.to_homogeneous()).norm() < 1e-12);
        // exp(ξ) exp(−ξ) = identity.
        let id = exp_se3(&xi) * exp_se3(&(-xi));
        assert!((id.to_homogeneous() - nalgebra::Matrix4::identity()).norm() < 1e-12);
    }

    #[test]
    fn exp_se3_is_the_matrix_exponential() {
        // Compare with a truncated power series of the 4×4 twist matrix.
        let xi = Vector6::new(0.7, -0.4, 0.2, 0.3, -1.0, 0.8);
        let mut x = nalgebra::Matrix4::zeros();
        x.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&hat(&Vector3::new(xi[0], xi[1], xi[2])));
        x.fixed_view_mut::<3, 1>(0, 3)
            .copy_from(&Vector3::new(xi[3], xi[4], xi[5]));
        let mut term = nalgebra::Matrix4::identity();
        let mut sum = term;
        for k in 1..40 {
            term = term * x / k as f64;
            sum += term;
        }
        assert!((exp_se3(&xi).to_homogeneous() - sum).norm() < 1e-12);
    }

    #[test]
    fn matrices_are_accepted_only_when_rigid() {
        let t = Isometry3::from_parts(
            Translation3::new(1.0, -2.0, 3e6),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.3, -1.2, 2.0)),
        );
        let m = t.to_homogeneous();
        let back = isometry_from_matrix(&m).unwrap();
        assert!((back.to_homogeneous() - m).amax() < 1e-9);
        // Printed with 4 decimals: still accepted, and re-orthonormalised.
        let rounded = m.map(|v| (v * 1e4).round() / 1e4);
        let r = isometry_from_matrix(&rounded).unwrap().rotation;
        assert!((r.to_rotation_matrix().matrix().determinant() - 1.0).abs() < 1e-12);
        assert!(rotation_angle(&r.to_rotation_matrix(), &t.rotation.to_rotation_matrix()) < 1e-4);
        let mut scaled = m;
        scaled.fixed_view_mut::<3, 3>(0, 0).scale_mut(1.1);
        let mut reflected = m;
        reflected.column_mut(0).neg_mut();
        let mut projective = m;
        projective[(3, 0)] = 0.5;
        let mut nan = m;
        nan[(1, 3)] = f64::NAN;
        for bad in [scaled, reflected, projective, nan] {
            assert!(isometry_from_matrix(&bad).is_none(), "{bad}");
        }
    }

    #[test]
    fn hat_vee_round_trip() {
        let w = Vector3::new(0.1, -2.0, 3.5);
        assert_eq!(vee(&hat(&w)), w);
        let x = Vector3::new(-1.0, 0.5, 2.0);
        assert!((hat(&w) * x - w.cross(&x)).norm() < 1e-15);
    }
}
