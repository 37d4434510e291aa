//! Motions of the source that the data do not determine, from the spectrum of `JᵀJ`.
//!
//! Moving the source along a twist ξ changes each residual Φ(xᵢ) by `Jᵢ ξ`. When some ξ changes
//! none of them — a sphere turned about its centre, a plane slid along itself, a bottle (a
//! surface of revolution) turned about its axis — the cost is flat along ξ and the pose there is
//! whatever the start and the optimiser's noise left: no method can recover it from geometry.
//! Such directions are the eigenvectors of `JᵀJ` with (relatively) tiny eigenvalues.
//!
//! To compare rotations with translations the matrix is taken about the moved source's centroid
//! `c`, with rotations scaled by the source's RMS radius `ρ` about it and divided by the number
//! of points: rows `[(x − c) × ∇Φ / ρ; ∇Φ]`, twist `[ρ ω; v]`. For a shape that constrains all
//! six directions the eigenvalues are of the order of 0.1 (unit gradients spread over the
//! directions); an eigenvalue below [`FREE_MOTION_RATIO`] × the largest marks a free motion.
//!
//! Measured on the 36 density pairs of `sdfreg eval` (ModelNet40): the two bottles' spin about
//! their axis lies at 3–4·10⁻⁴ of the largest eigenvalue; the least constrained of the other 34
//! shapes (a cup with a handle, a flat keyboard) at 3–4·10⁻³, the rest above 9·10⁻³. Φ's
//! gradients are only as exact as its fit (a few degrees off make ~10⁻³), so a procedural vase
//! fitted briefly sits at 1.1·10⁻³. The default threshold, 2·10⁻³, sits between.

use nalgebra::{Matrix6, Point3, SymmetricEigen, Unit, Vector3, Vector6};

use crate::solve::lm::jacobian_row;

/// Default threshold on an eigenvalue relative to the largest below which a motion is free.
pub const FREE_MOTION_RATIO: f64 = 2e-3;

/// What kind of motion a free direction is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MotionKind {
    /// A rotation about an axis (at least 90 % of the unit twist is rotation).
    Rotation,
    /// A translation along a direction (at least 90 % of the unit twist is translation).
    Translation,
    /// A coupled rotation and translation (a screw motion).
    Screw,
}

impl MotionKind {
    /// Lower-case name: `rotation`, `translation` or `screw`.
    pub fn name(&self) -> &'static str {
        match self {
            MotionKind::Rotation => "rotation",
            MotionKind::Translation => "translation",
            MotionKind::Screw => "screw",
        }
    }
}

/// A motion of the source that leaves the residuals (nearly) unchanged.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FreeMotion {
    /// Rotation, translation or screw.
    pub kind: MotionKind,
    /// Unit direction in the target frame: the rotation axis (for a screw, its rotation part's)
    /// or the translation direction.
    pub axis: Unit<Vector3<f64>>,
    /// A point of the rotation (or screw) axis, target frame, user units — the one closest to
    /// the moved source's centroid; for a translation, that centroid.
    pub point: Point3<f64>,
    /// The eigenvalue relative to the largest (0 = no constraint at all).
    pub relative_eigenvalue: f64,
}

impl std::fmt::Display for FreeMotion {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let a = self.axis;
        let p = self.point;
        match self.kind {
            MotionKind::Translation => {
                write!(f, "translation along ({:.3}, {:.3}, {:.3})", a.x, a.y, a.z)
            }
            kind => write!(
                f,
                "{} about the axis ({:.3}, {:.3}, {:.3}) through ({:.6}, {:.6}, {:.6})",
                kind.name(),
                a.x,
                a.y,
                a.z,
                p.x,
                p.y,
                p.z
            ),
        }?;
        write!(f, " (relative eigenvalue {:.1e})", self.relative_eigenvalue)
    }
}

/// The constraint spectrum of a registration: how well the data fix each direction of the pose.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Degeneracy {
    /// Eigenvalues of the normalised information matrix (see the module docs), ascending, each
    /// divided by the largest.
    pub relative_eigenvalues: [f64; 6],
    /// The free motions (relative eigenvalue below the threshold), least constrained first.
    pub free: Vec<FreeMotion>,
    /// With a scale (similarity registration): how well the data fix it once every rigid motion
    /// is let free to compensate — the Schur complement of the scale in the normalised matrix
    /// (scale column `∇Φ·(x − c)/ρ`), divided by the largest eigenvalue. A plane leaves it at 0
    /// (it looks the same at every scale); a sphere fixes it (its radius). `None` when rigid.
    #[serde(default)]
    pub scale_relative_eigenvalue: Option<f64>,
    /// The threshold the free motions were judged by.
    #[serde(default)]
    pub ratio: f64,
}

impl Degeneracy {
    /// Analyses moved source points `x` (target frame) with the SDF gradients `grad` at them;
    /// motions with an eigenvalue below `ratio` × the largest are free. Any consistent length
    /// unit works; the returned points are in it.
    pub fn analyse(x: &[Point3<f64>], grad: &[Vector3<f64>], ratio: f64) -> Self {
        let n = x.len().min(grad.len());
        if n == 0 {
            return Self::default();
        }
        let (c, rho) = centre_and_radius(&x[..n]);
        let mut m = Matrix6::zeros();
        for (p, g) in x[..n].iter().zip(&grad[..n]) {
            let j = jacobian_row(&((p.coords - c) / rho), g);
            if !j.iter().all(|v| v.is_finite()) {
                continue;
            }
            m += j * j.transpose();
        }
        m /= n as f64;
        let eig = SymmetricEigen::new(m);
        let mut order: Vec<usize> = (0..6).collect();
        order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
        let largest = eig.eigenvalues[order[5]].max(f64::MIN_POSITIVE);
        let mut relative = [0.0; 6];
        let mut free = Vec::new();
        for (k, &i) in order.iter().enumerate() {
            relative[k] = (eig.eigenvalues[i] / largest).max(0.0);
            if relative[k] < ratio {
                let e: Vector6<f64> = eig.eigenvectors.column(i).into_owned();
                free.push(classify(&e, &c, rho, relative[k]));
            }
        }
        Self {
            relative_eigenvalues: relative,
            free,
            scale_relative_eigenvalue: None,
            ratio,
        }
    }

    /// Adds the scale's constraint ([`Self::scale_relative_eigenvalue`]) for the moved source
    /// points `x` and the gradients `grad` of [`Self::analyse`].
    pub fn analyse_scale(&mut self, x: &[Point3<f64>], grad: &[Vector3<f64>]) {
        let n = x.len().min(grad.len());
        if n == 0 {
            return;
        }
        let (c, rho) = centre_and_radius(&x[..n]);
        let (mut m, mut b, mut d) = (Matrix6::zeros(), Vector6::zeros(), 0.0);
        for (p, g) in x[..n].iter().zip(&grad[..n]) {
            let y = (p.coords - c) / rho;
            let j = jacobian_row(&y, g);
            let e = g.dot(&y);
            if !(j.iter().all(|v| v.is_finite()) && e.is_finite()) {
                continue;
            }
            m += j * j.transpose();
            b += e * j;
            d += e * e;
        }
        let largest = SymmetricEigen::new(m)
            .eigenvalues
            .max()
            .max(d)
            .max(f64::MIN_POSITIVE);
        // Rigid directions the data leave free cannot compensate anything: a pseudo-inverse.
        let schur = match m.pseudo_inverse(1e-9 * largest) {
            Ok(inv) => d - (b.transpose() * inv * b)[0],
            Err(_) => d,
        };
        self.scale_relative_eigenvalue = Some((schur / largest).max(0.0));
    }

    /// Whether some motion is free.
    pub fn is_degenerate(&self) -> bool {
        !self.free.is_empty() || self.scale_free()
    }

    /// Whether the scale is free (similarity registration): its relative eigenvalue below the
    /// threshold.
    pub fn scale_free(&self) -> bool {
        self.scale_relative_eigenvalue
            .is_some_and(|v| v < self.ratio)
    }
}

/// The centroid `c` of `x` and its RMS radius `ρ` about it (at least the smallest positive
/// number): the frame the normalised matrix is taken in (see the module docs).
fn centre_and_radius(x: &[Point3<f64>]) -> (Vector3<f64>, f64) {
    let n = x.len() as f64;
    let c = x.iter().map(|p| p.coords).sum::<Vector3<f64>>() / n;
    let rho = (x.iter().map(|p| (p.coords - c).norm_squared()).sum::<f64>() / n)
        .sqrt()
        .max(f64::MIN_POSITIVE);
    (c, rho)
}

/// Names the unit twist `e = [ρω; v]` (about the centroid `c`).
fn classify(e: &Vector6<f64>, c: &Vector3<f64>, rho: f64, relative: f64) -> FreeMotion {
    let a = e.fixed_rows::<3>(0).into_owned();
    let v = e.fixed_rows::<3>(3).into_owned();
    let rot_share = a.norm_squared() / e.norm_squared().max(f64::MIN_POSITIVE);
    if rot_share < 0.1 {
        return FreeMotion {
            kind: MotionKind::Translation,
            axis: Unit::new_normalize(v),
            point: Point3::from(*c),
            relative_eigenvalue: relative,
        };
    }
    // Velocity of a point y: ω × (y − c) + v with ω = a/ρ. The axis passes through
    // c + ω × v / |ω|² (the component of v along ω is the screw's pitch).
    let omega = a / rho;
    let point = c + omega.cross(&v) / omega.norm_squared();
    FreeMotion {
        kind: if rot_share > 0.9 {
            MotionKind::Rotation
        } else {
            MotionKind::Screw
        },
        axis: Unit::new_normalize(omega),
        point: Point3::from(point),
        relative_eigenvalue: relative,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::shapes::fibonacci_sphere;

    /// Points on a surface with their unit normals standing in for ∇Φ.
    fn analyse(points: &[(Point3<f64>, Vector3<f64>)]) -> Degeneracy {
        let x: Vec<Point3<f64>> = points.iter().map(|p| p.0).collect();
        let g: Vec<Vector3<f64>> = points.iter().map(|p| p.1).collect();
        Degeneracy::analyse(&x, &g, FREE_MOTION_RATIO)
    }

    #[test]
    fn an_ellipsoid_constrains_everything() {
        let pts: Vec<_> = fibonacci_sphere(2000)
            .into_iter()
            .map(|d| {
                let s = Vector3::new(1.0, 0.6, 0.3);
                let p = d.component_mul(&s);
                (Point3::from(p), d.component_div(&s).normalize())
            })
            .collect();
        let d = analyse(&pts);
        assert!(!d.is_degenerate(), "{:?}", d.relative_eigenvalues);
        assert!(
            d.relative_eigenvalues[0] > 0.02,
            "{:?}",
            d.relative_eigenvalues
        );
    }

    #[test]
    fn a_sphere_is_free_to_turn_about_its_centre() {
        let centre = Vector3::new(3.0, -2.0, 5.0);
        let pts: Vec<_> = fibonacci_sphere(2000)
            .into_iter()
            .map(|d| (Point3::from(centre + 0.5 * d), d))
            .collect();
        let d = analyse(&pts);
        assert_eq!(d.free.len(), 3, "{:?}", d.relative_eigenvalues);
        for f in &d.free {
            assert_eq!(f.kind, MotionKind::Rotation);
            assert!((f.point.coords - centre).norm() < 1e-4, "{}", f);
        }
    }

    #[test]
    fn a_plane_slides_in_itself_and_spins_about_its_normal() {
        let n = Vector3::new(1.0, 2.0, 2.0) / 3.0;
        let u = n.cross(&Vector3::x()).normalize();
        let w = n.cross(&u);
        let mut pts = Vec::new();
        for i in 0..40 {
            for j in 0..40 {
                let p = u * (i as f64 / 40.0) + w * (j as f64 / 20.0) + n * 7.0;
                pts.push((Point3::from(p), n));
            }
        }
        let d = analyse(&pts);
        assert_eq!(d.free.len(), 3, "{:?}", d.relative_eigenvalues);
        let translations: Vec<_> = d
            .free
            .iter()
            .filter(|f| f.kind == MotionKind::Translation)
            .collect();
        assert_eq!(translations.len(), 2);
        for f in translations {
            assert!(f.axis.dot(&n).abs() < 1e-6, "{}", f);
        }
        let spin = d.free.iter().find(|f| f.kind == MotionKind::Rotation);
        assert!(spin.unwrap().axis.dot(&n).abs() > 1.0 - 1e-6);
    }

    #[test]
    fn a_cylinder_spins_about_and_slides_along_its_axis() {
        // An open tube of radius 0.3 along the direction `a` through `o`.
        let a = Vector3::new(0.0, 0.6, 0.8);
        let u = Vector3::x();
        let w = a.cross(&u);
        let o = Vector3::new(1.0, 2.0, 3.0);
        let mut pts = Vec::new();
        for i in 0..60 {
            let t = i as f64 / 60.0 * std::f64::consts::TAU;
            let radial = u * t.cos() + w * t.sin();
            for j in 0..30 {
                let p = o + 0.3 * radial + a * (j as f64 / 30.0 - 0.5) * 2.0;
                pts.push((Point3::from(p), radial));
            }
        }
        let d = analyse(&pts);
        assert_eq!(d.free.len(), 2, "{:?}", d.relative_eigenvalues);
        for f in &d.free {
            assert!(f.axis.dot(&a).abs() > 1.0 - 1e-6, "{}", f);
            if f.kind == MotionKind::Rotation {
                // The axis passes through `o`.
                let off = (f.point.coords - o) - a * a.dot(&(f.point.coords - o));
                assert!(off.norm() < 1e-6, "{}", f);
            }
        }
    }
}
