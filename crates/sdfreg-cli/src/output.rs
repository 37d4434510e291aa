//! How the CLI writes results: 4×4 matrices as text, and registrations as JSON with the same
//! snake_case names as the Python binding (`stop_reason: "small_step"`, `stages`, …).

use nalgebra::Matrix4;
use sdfreg_core::{Degeneracy, Registration};

/// The 4×4 as four lines of four numbers, each written by `number`.
pub fn matrix_lines(m: &Matrix4<f64>, number: impl Fn(f64) -> String) -> String {
    matrix_rows(m)
        .iter()
        .map(|row| row.iter().map(|&v| number(v)).collect::<Vec<_>>().join(" ") + "\n")
        .collect()
}

/// The 4×4 as four lines of four numbers with 9 decimals (what `register` prints).
pub fn matrix_text(m: &Matrix4<f64>) -> String {
    matrix_lines(m, |v| format!("{v:.9}"))
}

pub use sdfreg_core::geometry::se3::matrix_rows;

/// The free motions as JSON objects: `kind`, `axis`, `point`, `relative_eigenvalue`.
pub fn free_motions_json(d: &Degeneracy) -> serde_json::Value {
    d.free
        .iter()
        .map(|f| {
            serde_json::json!({
                "kind": f.kind.name(),
                "axis": [f.axis.x, f.axis.y, f.axis.z],
                "point": [f.point.x, f.point.y, f.point.z],
                "relative_eigenvalue": f.relative_eigenvalue,
            })
        })
        .collect()
}

/// A registration as the JSON object `register --output FILE.json` writes.
pub fn registration_json(r: &Registration) -> serde_json::Value {
    let mut json = serde_json::json!({
        "transformation": matrix_rows(&r.matrix()),
        "converged": r.converged,
        "stop_reason": r.stop_reason.name(),
        "fitness": r.fitness,
        "robust": r.robust,
        "inlier_rmse": r.inlier_rmse,
        "inlier_distance": r.inlier_distance,
        "iterations": r.iterations,
        "cost": r.cost,
        "information": matrix_rows(&r.information),
        "constraint_eigenvalues": r.degeneracy.relative_eigenvalues,
        "free_motions": free_motions_json(&r.degeneracy),
        "stages": r.stages,
        "time_ms": r.time.as_secs_f64() * 1e3,
        "stage_ms": stage_ms(r),
        "points_left_out": {"source": r.source_left_out, "target": r.target_left_out},
    });
    if let Some(info) = &r.similarity_information {
        json["scale"] = r.scale.into();
        json["similarity_information"] = serde_json::json!(matrix_rows(info));
        json["scale_relative_eigenvalue"] = r.degeneracy.scale_relative_eigenvalue.into();
        json["scale_free"] = r.degeneracy.scale_free().into();
    }
    json
}

/// Each stage's wall time, milliseconds (`Registration::stage_times`).
fn stage_ms(r: &Registration) -> serde_json::Value {
    r.stage_times
        .named()
        .iter()
        .map(|(name, t)| (name.to_string(), serde_json::json!(t.as_secs_f64() * 1e3)))
        .collect::<serde_json::Map<_, _>>()
        .into()
}

/// The one-line summary `register` prints on stderr.
pub fn summary_line(r: &Registration) -> String {
    let scale = match r.similarity_information {
        Some(_) => format!(", scale {:.6}", r.scale),
        None => String::new(),
    };
    format!(
        "{} ({}) after {} LM iterations{scale}, fitness {:.3}{}, inlier RMSE {:.3e}, {:.0} ms",
        if r.converged {
            "converged"
        } else {
            "not converged"
        },
        r.stop_reason.name(),
        r.iterations,
        r.fitness,
        if r.robust { " (robust kernel)" } else { "" },
        r.inlier_rmse,
        r.time.as_secs_f64() * 1e3
    )
}
