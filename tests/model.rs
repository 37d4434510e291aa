//! The fitted target as a model: fit once, register many, save and load bit-identically.

use nalgebra::Point3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use sdfreg_core::se3::pose_errors;
use sdfreg_core::{register, shapes, IoError, SdfModel};

use crate::common::{motion, moved, quick};

#[test]
fn a_saved_model_registers_bit_identically_after_loading() {
    let target = shapes::blob(1024, &mut ChaCha8Rng::seed_from_u64(11));
    let s = quick();
    let model = SdfModel::fit(&target, &s).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("blob.sdfm");
    model.save(&path).unwrap();
    let loaded = SdfModel::load(&path).unwrap();
    // Saving again writes the same bytes.
    assert_eq!(loaded.to_bytes(), std::fs::read(&path).unwrap());
    for (k, m) in [
        motion(30.0, [0.1, 0.2, -0.1]),
        motion(120.0, [-0.3, 0.0, 0.2]),
    ]
    .iter()
    .enumerate()
    {
        let source: Vec<Point3<f64>> = moved(
            &shapes::blob(700, &mut ChaCha8Rng::seed_from_u64(k as u64)),
            m,
        );
        let a = model.register(&source, None, &s).unwrap();
        let b = loaded.register(&source, None, &s).unwrap();
        assert_eq!(a.t_target_source, b.t_target_source);
        assert_eq!((a.fitness, a.cost, a.stages), (b.fitness, b.cost, b.stages));
        let (rot, tr) = pose_errors(&a.t_target_source, &m.inverse());
        assert!(
            rot < 1.0 && tr < 0.01,
            "frozen model, pair {k}: {rot}°, {tr}"
        );
        let a = model.register_refined(&source, None, &s).unwrap();
        let b = loaded.register_refined(&source, None, &s).unwrap();
        assert_eq!(a.t_target_source, b.t_target_source);
        // Refining against the model is register() itself.
        let direct = register(&source, &target, None, &s).unwrap();
        assert_eq!(direct.t_target_source, a.t_target_source);
    }
}

#[test]
fn a_missing_or_foreign_model_file_is_a_typed_error() {
    let dir = tempfile::tempdir().unwrap();
    let missing = SdfModel::load(dir.path().join("none.sdfm")).unwrap_err();
    assert!(matches!(missing, IoError::Io { .. }), "{missing}");
    let ply = dir.path().join("cloud.sdfm");
    std::fs::write(&ply, "ply\nformat ascii 1.0\nend_header\n").unwrap();
    let err = SdfModel::load(&ply).unwrap_err();
    assert!(matches!(err, IoError::BadModel { .. }), "{err}");
    assert!(
        err.to_string().starts_with(&format!("{}: ", ply.display())),
        "{err}"
    );
}
