//! Scenes: procedural LiDAR pairs of a street and a room (ray cast with parry3d, no data
//! files) registered with the default settings, which choose the local model for them.

use sdfreg_core::geometry::se3::pose_errors;
use sdfreg_core::sim::lidar::{room_pair, street_pair};
use sdfreg_core::{register, ModelKind, RegisterSettings, SdfModel};

#[test]
fn a_street_pair_registers_with_the_defaults_where_the_global_model_slides() {
    let pair = street_pair();
    let s = RegisterSettings::default();
    // The target's extent against its point spacing chooses the local model.
    let model = SdfModel::fit(&pair.target, &s).unwrap();
    assert_eq!(model.kind(), ModelKind::Local);
    let voxel = model.voxel().unwrap();
    assert!((0.5..2.0).contains(&voxel), "voxel {voxel} m");
    let r = register(&pair.source, &pair.target, None, &s).unwrap();
    let (rot, trans) = pose_errors(&r.t_target_source, &pair.t_target_source);
    assert!(rot <= 0.1 && trans <= 0.02, "{rot}° {trans} m");
    // Against the stored model too.
    let r = model.register(&pair.source, None, &s).unwrap();
    let (rot, trans) = pose_errors(&r.t_target_source, &pair.t_target_source);
    assert!(
        rot <= 0.1 && trans <= 0.02,
        "against the model: {rot}° {trans} m"
    );
    // One MLP over the 143 m street smooths away what pins the slide along it.
    let mut global = s.clone();
    global.fit.local.kind = ModelKind::Global;
    let r = register(&pair.source, &pair.target, None, &global).unwrap();
    let (_, trans) = pose_errors(&r.t_target_source, &pair.t_target_source);
    assert!(trans > 0.5, "the global model ends {trans} m off");
}

#[test]
fn a_room_pair_registers_with_the_defaults() {
    let pair = room_pair();
    let r = register(
        &pair.source,
        &pair.target,
        None,
        &RegisterSettings::default(),
    )
    .unwrap();
    let (rot, trans) = pose_errors(&r.t_target_source, &pair.t_target_source);
    assert!(rot <= 0.1 && trans <= 0.01, "{rot}° {trans} m");
}

#[test]
fn a_local_model_saves_and_loads_with_the_same_registrations() {
    let pair = street_pair();
    let s = RegisterSettings::default();
    let model = SdfModel::fit(&pair.target, &s).unwrap();
    let bytes = model.to_bytes();
    let back = SdfModel::from_bytes(&bytes, std::path::Path::new("street.sdfm")).unwrap();
    assert_eq!(back.kind(), ModelKind::Local);
    assert_eq!(back.local_parameters(), model.local_parameters());
    let a = model.register(&pair.source, None, &s).unwrap();
    let b = back.register(&pair.source, None, &s).unwrap();
    assert_eq!(a.t_target_source, b.t_target_source);
    // Queries read the local part too: on the target's points Φ is near 0 (metres).
    let d = back.distance(&pair.target[..2000]);
    let mut abs: Vec<f64> = d.iter().map(|v| v.abs()).collect();
    abs.sort_by(f64::total_cmp);
    assert!(
        abs[abs.len() / 2] < 0.3,
        "median |Φ| {} m",
        abs[abs.len() / 2]
    );
    // Asked for, the global kind holds no corrections.
    let mut other = s.clone();
    other.fit.local.kind = ModelKind::Global;
    let global = SdfModel::fit(&pair.target[..5000], &other).unwrap();
    assert_eq!(global.kind(), ModelKind::Global);
    assert_eq!(global.local_parameters(), 0);
}
