//! The fitted target as an object: fit Φ once, then register many sources against it, query it,
//! save it and load it.
//!
//! [`SdfModel::fit`] runs the first two stages of [`crate::register()`] on the target alone
//! (normalise, pre-fit Φ) and keeps everything a registration needs of the target: the
//! normalisation, Φ with the state of its fit (optimiser moments, random stream), and the
//! (subsampled) target points the polish, the shift search and the quality figures use.
//! [`SdfModel::register`] runs the remaining stages against it with Φ frozen — no Adam step, the
//! cost of a registration without the 85 % that fitting takes; [`SdfModel::register_refined`]
//! refines a private copy of Φ with the moved source among its queries, as
//! [`crate::register()`] does (same numbers, for targets within
//! [`crate::RegisterSettings::max_target_points`]).
//!
//! Queries ([`SdfModel::distance`], [`SdfModel::gradient`], [`SdfModel::closest_points`]) take and
//! return the target's own units and frame. Files: [`SdfModel::save`] / [`SdfModel::load`]
//! (`.sdfm`, a safetensors file; layout in [`crate::model::file`]).

use std::sync::{Arc, OnceLock};

use nalgebra::{Matrix4, Point3, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::base::error::{Error, Role};
use crate::field::baked::BakedGrid;
use crate::field::local_grid::{ModelKind, SparseBaked};
use crate::field::mlp::{Mlp, MlpSettings};
use crate::fit::fitter::SdfFitter;
use crate::fit::settings::FitSettings;
use crate::geometry::cloud::{usable, LeftOut, Normalization};
use crate::geometry::planes::SharedPlanes;
use crate::pipeline::evaluate::{Evaluation, MovedSource};
use crate::pipeline::registration::Registration;
use crate::pipeline::report::Stage;
use crate::pipeline::settings::{RegisterSettings, MIN_POINTS};
use crate::pipeline::surface::WithGrid;
use crate::pipeline::target::prefit;
use crate::solve::measure::nearest_distances2;

/// A target fitted once: its normalisation, Φ (with the state of its fit) and the target
/// points. Fit once with [`SdfModel::fit`], then register many sources against it, track, query,
/// mesh, save and load it; `.sdfm` files are safetensors ([`crate::model::file`]).
///
/// ```no_run
/// use sdfreg_core::{io::read_point_cloud, RegisterSettings, SdfModel};
/// let settings = RegisterSettings::default();
/// let model = SdfModel::fit(&read_point_cloud("map.ply")?, &settings)?;
/// model.save("map.sdfm")?;
/// let r = model.register(&read_point_cloud("scan.ply")?, None, &settings)?; // Φ frozen
/// let d = model.distance(&[nalgebra::Point3::new(0.0, 0.0, 0.0)]); // target units
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Clone, Debug)]
pub struct SdfModel {
    pub(crate) norm: Normalization,
    pub(crate) fitter: SdfFitter,
    pub(crate) mlp: MlpSettings,
    pub(crate) seed: u64,
    /// Φ baked into a grid for the multi-start ([`crate::field::baked`]): made by
    /// [`SdfModel::fit`] for an object's (global) model, else by the first registration that
    /// runs the multi-start (a scene's model registered from a given pose never needs it);
    /// derived from Φ alone, so it is not stored in files.
    pub(crate) grid: OnceLock<Arc<BakedGrid>>,
    /// The polish planes at the target's points (a scene's, or an object's with
    /// [`crate::PolishSettings::target_planes`]), computed by the registrations as they
    /// need them and kept for the next ones.
    pub(crate) planes: SharedPlanes,
    /// A local model's Φ at the corners of its grid ([`crate::field::local_grid::SparseBaked`]), made
    /// with [`Self::grid`] and, like it, not stored in files.
    pub(crate) corners: OnceLock<Vec<f32>>,
}

impl SdfModel {
    /// Fits Φ to `target` (user units and frame) with `settings.mlp`, `settings.fit` (its
    /// `model_prefit_steps` for a global Φ, `local.prefit_steps` for a local one),
    /// `settings.max_target_points` and `settings.seed`; the other settings are the
    /// registration's.
    pub fn fit(target: &[Point3<f64>], settings: &RegisterSettings) -> Result<Self, Error> {
        Self::fit_with_progress(target, settings, &|_| {})
    }

    /// [`SdfModel::fit`] with a progress callback (the pre-fit's steps).
    pub fn fit_with_progress(
        target: &[Point3<f64>],
        settings: &RegisterSettings,
        progress: &(dyn Fn(Stage) + Sync),
    ) -> Result<Self, Error> {
        settings.validate()?;
        let (target, _) = usable(target, Role::Target, MIN_POINTS)?;
        crate::base::pool::in_pool(settings.threads, || {
            // The registration's random stream, as `register()` draws it, so that a refined
            // registration against the model keeps `register()`'s numbers (with the same
            // pre-fit steps).
            let mut rng = ChaCha8Rng::seed_from_u64(settings.seed);
            let (norm, fitter) = prefit(&target, settings, true, &mut rng, progress)?;
            let model = Self {
                norm,
                fitter,
                mlp: settings.mlp.clone(),
                seed: settings.seed,
                grid: OnceLock::new(),
                planes: SharedPlanes::default(),
                corners: OnceLock::new(),
            };
            // An object's registrations read the grid at once (the multi-start); a scene's only
            // from no pose, so its grid waits for the first that does.
            if model.fitter.field().grid().is_none() {
                model.baked_grid();
            }
            model.baked_corners();
            Ok(model)
        })?
    }

    /// Φ baked into a grid (made on the first call).
    pub(crate) fn baked_grid(&self) -> &BakedGrid {
        crate::field::baked::baked_once(&self.grid, self.fitter.field())
    }

    /// Φ at the corners of a local model's grid (made on the first call); empty for a global
    /// model.
    pub(crate) fn baked_corners(&self) -> &[f32] {
        // Evaluated by rayon tasks: see `get_or_make`.
        crate::base::pool::get_or_make::<Vec<f32>>(&self.corners, || {
            match self.fitter.field().grid() {
                Some(grid) => {
                    crate::field::Field::eval_points(
                        self.fitter.field(),
                        &grid.corner_positions(),
                        false,
                    )
                    .0
                }
                None => Vec::new(),
            }
        })
    }

    /// The model as the registration stages see it with Φ frozen.
    pub(crate) fn frozen(&self) -> WithGrid<'_, SdfFitter> {
        let frozen = WithGrid::lazy(&self.fitter, &self.grid).with_planes(&self.planes);
        match self.fitter.field().grid() {
            Some(grid) => frozen.with_sparse(SparseBaked::new(grid, self.baked_corners())),
            None => frozen,
        }
    }

    /// Registers `source` (user units) onto the model with Φ frozen: the multi-start (or
    /// `init`, mapping source into target), LM, the robust re-run when needed, the polish and
    /// the shift search, as [`crate::register()`] minus every Φ refinement. `settings.mlp`,
    /// `settings.fit` (but for `refine_*`) and `settings.max_target_points` are the model's and
    /// are not read.
    pub fn register(
        &self,
        source: &[Point3<f64>],
        init: Option<&nalgebra::Isometry3<f64>>,
        settings: &RegisterSettings,
    ) -> Result<Registration, Error> {
        crate::pipeline::register::against(
            &self.norm,
            &self.frozen(),
            source,
            init,
            settings,
            false,
            &|_| {},
        )
    }

    /// [`SdfModel::register`] refining a private copy of Φ in the coarse-to-fine loop with the
    /// moved source among its queries (paper eq. 18-1), as [`crate::register()`] does; the
    /// model is not changed. With [`crate::FitSettings::model_prefit_steps`] equal to
    /// `prefit_steps` (the model's pre-fit and a full call's the same), its numbers are
    /// [`crate::register()`]'s.
    pub fn register_refined(
        &self,
        source: &[Point3<f64>],
        init: Option<&nalgebra::Isometry3<f64>>,
        settings: &RegisterSettings,
    ) -> Result<Registration, Error> {
        crate::pipeline::register::against(
            &self.norm,
            &self.fitter,
            source,
            init,
            settings,
            true,
            &|_| {},
        )
    }

    /// Φ's zero level set as a triangle mesh, for looking at what was fitted: Φ sampled on a
    /// grid of `resolution` cells along the target's largest side (over the target points'
    /// bounding box and a margin of 5 % and 2 cells), then Surface Nets (`fast-surface-nets`).
    /// Vertices in the target's units and frame, triangles as vertex indices (outward normals by
    /// the right-hand rule). `resolution` from 4 to 1024. For a local model (a scene) only the
    /// triangles within a voxel of the target's points are kept: beyond, Φ is the MLP's alone,
    /// whose zero level set there is no surface the scan saw.
    pub fn mesh(&self, resolution: usize) -> Result<crate::io::MeshData, Error> {
        use fast_surface_nets::ndshape::{RuntimeShape, Shape};
        use fast_surface_nets::{surface_nets, SurfaceNetsBuffer};
        if !(4..=1024).contains(&resolution) {
            return Err(Error::InvalidSetting {
                name: "resolution",
                reason: format!("must be from 4 to 1024 cells, got {resolution}"),
            });
        }
        let cell = 1.0 / resolution as f64;
        let target = self.fitter.target();
        let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        for p in target {
            for k in 0..3 {
                lo[k] = lo[k].min(p[k] as f64);
                hi[k] = hi[k].max(p[k] as f64);
            }
        }
        let margin = 0.05 + 2.0 * cell;
        let origin = lo.map(|v| v - margin);
        let dims: [u32; 3] =
            std::array::from_fn(|k| ((hi[k] - lo[k] + 2.0 * margin) / cell).ceil() as u32 + 1);
        let shape = RuntimeShape::<u32, 3>::new(dims);
        let grid: Vec<[f32; 3]> = (0..shape.size())
            .map(|i| {
                let c = shape.delinearize(i);
                std::array::from_fn(|k| (origin[k] + c[k] as f64 * cell) as f32)
            })
            .collect();
        let sdf = crate::field::Field::eval_points(self.fitter.field(), &grid, false).0;
        let mut buffer = SurfaceNetsBuffer::default();
        surface_nets(&sdf, &shape, [0; 3], dims.map(|d| d - 1), &mut buffer);
        let unit: Vec<[f32; 3]> = buffer
            .positions
            .iter()
            .map(|p| std::array::from_fn(|k| (origin[k] + p[k] as f64 * cell) as f32))
            .collect();
        let mut triangles: Vec<[usize; 3]> = buffer
            .indices
            .chunks_exact(3)
            .map(|t| [t[0] as usize, t[1] as usize, t[2] as usize])
            .collect();
        let mut keep: Vec<bool> = vec![true; unit.len()];
        if let Some(grid) = self.fitter.field().grid() {
            // A scene's Φ is the MLP's alone beyond the corrections' band: its zero level set
            // there is no surface the scan saw. Keep the triangles whose centre lies within a
            // voxel (or two cells) of a target point.
            let reach = (grid.voxel() as f64).max(2.0 * cell).powi(2) as f32;
            let tree = self.fitter.tree();
            triangles.retain(|t| {
                let c: [f32; 3] =
                    std::array::from_fn(|k| (unit[t[0]][k] + unit[t[1]][k] + unit[t[2]][k]) / 3.0);
                tree.nearest_one::<kiddo::SquaredEuclidean>(&c).distance <= reach
            });
            keep.fill(false);
            for t in &triangles {
                for &i in t {
                    keep[i] = true;
                }
            }
        }
        // Vertices no triangle uses are left out, the rest renumbered in order.
        let mut index = vec![usize::MAX; unit.len()];
        let mut vertices = Vec::new();
        for (i, p) in unit.iter().enumerate() {
            if keep[i] {
                index[i] = vertices.len();
                vertices.push(self.norm.to_user(&Vector3::from_fn(|k, _| p[k] as f64)));
            }
        }
        for t in &mut triangles {
            *t = t.map(|i| index[i]);
        }
        Ok((vertices, triangles))
    }

    /// The network Φ (unit frame: see [`SdfModel::normalization`]).
    pub fn mlp(&self) -> &Mlp {
        self.fitter.mlp()
    }

    /// The similarity from the target's frame into Φ's unit frame.
    pub fn normalization(&self) -> Normalization {
        self.norm
    }

    /// The target points Φ was fitted to (subsampled), in the target's units and frame.
    pub fn target_points(&self) -> Vec<Point3<f64>> {
        self.fitter
            .target()
            .iter()
            .map(|p| {
                self.norm
                    .to_user(&Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64))
            })
            .collect()
    }

    /// How well `source`, moved by `transformation` (source into the target's frame, `p_target
    /// = s R p_source + t`, rigid or a similarity), lies on the target points this model was
    /// fitted to ([`Self::target_points`]): [`crate::evaluate_registration`] against them, at
    /// `max_distance` in the target's units. A target of more than
    /// [`RegisterSettings::max_target_points`] was fitted from a subsample, and the figures are
    /// then against that subsample (a lower fitness at distances near its spacing). The
    /// target's left-out counts are 0: its fit left those points out.
    ///
    /// # Errors
    /// As [`crate::evaluate_registration`], for the source, `max_distance` and
    /// `transformation`.
    pub fn evaluate_registration(
        &self,
        source: &[Point3<f64>],
        transformation: &Matrix4<f64>,
        max_distance: f64,
    ) -> Result<Evaluation, Error> {
        MovedSource::new(source, transformation, max_distance)?.measured(
            &self.norm,
            LeftOut::default(),
            |moved| nearest_distances2(self.fitter.tree(), moved),
        )
    }

    /// The seed the model was fitted with.
    pub fn seed(&self) -> u64 {
        self.seed
    }

    /// Whether `r`, a registration against this model with `settings`, would have run again
    /// with a global Φ in a full call ([`crate::LocalSettings::global_rerun_below_fitness`]):
    /// the model is local and `r` fits less than that share of the source. A stored model
    /// cannot; the CLI and Python warn, naming the global kind (scans that overlap only in
    /// part register more reliably against it).
    pub fn fits_poorly(&self, r: &Registration, settings: &RegisterSettings) -> bool {
        self.kind() == ModelKind::Local && r.fitness < settings.fit.local.global_rerun_below_fitness
    }

    /// The kind of Φ the fit made: [`ModelKind::Global`] or [`ModelKind::Local`]
    /// ([`crate::LocalSettings::kind`] `Auto` decided from the target).
    pub fn kind(&self) -> ModelKind {
        if self.fitter.field().grid().is_some() {
            ModelKind::Local
        } else {
            ModelKind::Global
        }
    }

    /// A local model's voxel side, in the target's units; `None` for a global model.
    pub fn voxel(&self) -> Option<f64> {
        let grid = self.fitter.field().grid()?;
        Some(grid.voxel() as f64 * self.norm.scale)
    }

    /// The local grid's corrections (one per voxel corner near the target); 0 for a global
    /// model.
    pub fn local_parameters(&self) -> usize {
        self.fitter.field().theta().len()
    }

    /// Φ's settings: the network's, and the fit's.
    pub fn settings(&self) -> (&MlpSettings, &FitSettings) {
        (&self.mlp, self.fitter.settings())
    }

    /// Φ and ∇Φ at `points` (target units and frame): the signed distance in those units and
    /// its gradient (unit-free), evaluated in parallel.
    pub fn evaluate(&self, points: &[Point3<f64>]) -> (Vec<f64>, Vec<Vector3<f64>>) {
        crate::field::evaluate_user(&self.norm, self.fitter.field(), points)
    }

    /// Signed distance Φ at `points`, in the target's units (positive outside).
    pub fn distance(&self, points: &[Point3<f64>]) -> Vec<f64> {
        self.evaluate(points).0
    }

    /// ∇Φ at `points` (unit-free; about unit length near the surface).
    pub fn gradient(&self, points: &[Point3<f64>]) -> Vec<Vector3<f64>> {
        self.evaluate(points).1
    }

    /// The closest surface point of each of `points`: `p − Φ(p) ∇Φ(p)/‖∇Φ(p)‖` (the projection
    /// the fit trains, paper eq. 18), target units and frame.
    pub fn closest_points(&self, points: &[Point3<f64>]) -> Vec<Point3<f64>> {
        crate::field::closest_user(points, self.evaluate(points))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    fn quick() -> RegisterSettings {
        let mut s = RegisterSettings::default();
        s.fit.prefit_steps = 300;
        s.fit.model_prefit_steps = 300;
        s
    }

    /// A model of a sphere of radius 50 around (1000, 0, 0), in millimetres.
    fn sphere_model() -> (SdfModel, Vector3<f64>) {
        let centre = Vector3::new(1000.0, 0.0, 0.0);
        let target: Vec<Point3<f64>> = crate::sim::shapes::fibonacci_sphere(2000)
            .iter()
            .map(|d| Point3::from(centre + d * 50.0))
            .collect();
        (SdfModel::fit(&target, &quick()).unwrap(), centre)
    }

    #[test]
    fn the_mesh_of_a_sphere_model_is_a_closed_outward_sphere() {
        let (model, centre) = sphere_model();
        let (v, t) = model.mesh(48).unwrap();
        assert!(t.len() > 1000, "{} triangles", t.len());
        let worst = v
            .iter()
            .map(|p| ((p.coords - centre).norm() - 50.0).abs())
            .fold(0.0, f64::max);
        assert!(worst < 2.0, "a vertex {worst} mm off the sphere");
        // Divergence theorem: the enclosed volume, positive when the normals point outward.
        let volume: f64 = t
            .iter()
            .map(|&[a, b, c]| {
                let (a, b, c) = (
                    v[a].coords - centre,
                    v[b].coords - centre,
                    v[c].coords - centre,
                );
                a.dot(&b.cross(&c)) / 6.0
            })
            .sum();
        let sphere = 4.0 / 3.0 * std::f64::consts::PI * 50f64.powi(3);
        assert!(
            (volume / sphere - 1.0).abs() < 0.05,
            "volume {volume} vs {sphere}"
        );
        assert!(matches!(model.mesh(2), Err(Error::InvalidSetting { .. })));
    }

    #[test]
    fn a_sphere_model_measures_distance_in_the_targets_units() {
        let (model, centre) = sphere_model();
        let probes = [
            Point3::from(centre + Vector3::new(60.0, 0.0, 0.0)),
            Point3::from(centre + Vector3::new(0.0, -45.0, 0.0)),
            Point3::from(centre + Vector3::new(0.0, 30.0, 40.0) * 1.1),
        ];
        let d = model.distance(&probes);
        for (p, d) in probes.iter().zip(&d) {
            let truth = (p.coords - centre).norm() - 50.0;
            assert!((d - truth).abs() < 1.5, "{d} vs {truth} mm");
        }
        for (p, q) in probes.iter().zip(model.closest_points(&probes)) {
            let r = (q.coords - centre).norm();
            assert!((r - 50.0).abs() < 1.5, "closest point at radius {r}");
            let along = (q - p).normalize().dot(&(centre - p.coords).normalize());
            assert!(along.abs() > 0.99, "not radial: {along}");
        }
        let g = model.gradient(&probes[..1]);
        assert!((g[0].normalize() - Vector3::x()).norm() < 0.1, "{:?}", g[0]);
    }

    #[test]
    fn refined_registration_against_a_model_equals_register() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let target = crate::sim::shapes::blob(800, &mut rng);
        let m =
            nalgebra::Isometry3::new(Vector3::new(0.1, -0.2, 0.05), Vector3::new(0.3, 0.2, -0.1));
        let source: Vec<Point3<f64>> = target.iter().map(|p| m * p).collect();
        let mut s = quick();
        s.coarse_to_fine.alternations = 4;
        let direct = crate::register(&source, &target, None, &s).unwrap();
        let model = SdfModel::fit(&target, &s).unwrap();
        let refined = model.register_refined(&source, None, &s).unwrap();
        assert_eq!(direct.t_target_source, refined.t_target_source);
        assert_eq!(direct.stages, refined.stages);
        let frozen = model.register(&source, None, &s).unwrap();
        let (rot, tr) = crate::geometry::se3::pose_errors(&frozen.t_target_source, &m.inverse());
        assert!(rot < 0.5 && tr < 0.005, "frozen Φ: {rot}°, {tr}");
    }

    #[test]
    fn a_scene_model_bakes_its_multistart_grid_only_when_a_registration_needs_it() {
        let pair = crate::sim::lidar::street_pair();
        let s = RegisterSettings::default();
        let model = SdfModel::fit(&pair.target, &s).unwrap();
        assert_eq!(model.kind(), ModelKind::Local);
        assert!(model.grid.get().is_none(), "a scene's fit bakes no grid");
        let path = std::path::Path::new("street.sdfm");
        let lazy = SdfModel::from_bytes(&model.to_bytes(), path).unwrap();
        let eager = SdfModel::from_bytes(&model.to_bytes(), path).unwrap();
        eager.baked_grid();
        // From a given pose: no multi-start, so no grid; the same answer as with one.
        let guess = Some(&pair.t_target_source);
        let given = lazy.register(&pair.source, guess, &s).unwrap();
        assert!(
            lazy.grid.get().is_none(),
            "baked for a registration from a pose"
        );
        let with_grid = eager.register(&pair.source, guess, &s).unwrap();
        assert_eq!(given.t_target_source, with_grid.t_target_source);
        // From nothing: the multi-start bakes it, the same grid, the same answer.
        let found = lazy.register(&pair.source, None, &s).unwrap();
        assert!(lazy.grid.get().is_some(), "the multi-start baked no grid");
        assert!(
            lazy.baked_grid().same_bits(eager.baked_grid()),
            "another grid"
        );
        let with_grid = eager.register(&pair.source, None, &s).unwrap();
        assert_eq!(found.t_target_source, with_grid.t_target_source);
        let (rot, tr) =
            crate::geometry::se3::pose_errors(&found.t_target_source, &pair.t_target_source);
        assert!(rot < 0.1 && tr < 0.01, "{rot}°, {tr} m");
    }

    #[test]
    fn a_loaded_model_registers_from_a_callers_parallel_loop() {
        // Its grid is baked by the first registration, whose rayon tasks a worker of the
        // caller's pool may wait on while taking up the next registration, which asks for the
        // same grid (a cell that waits for its maker could then wait on itself; rare here, see
        // `field::baked`'s test that asks from within the bake). Every answer the same.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let target = crate::sim::shapes::blob(800, &mut rng);
        let mut s = quick();
        s.threads = 1;
        let model = SdfModel::fit(&target, &s).unwrap();
        let loaded =
            SdfModel::from_bytes(&model.to_bytes(), std::path::Path::new("blob.sdfm")).unwrap();
        let m =
            nalgebra::Isometry3::new(Vector3::new(0.1, -0.2, 0.05), Vector3::new(0.3, 0.2, -0.1));
        let source: Vec<Point3<f64>> = target.iter().map(|p| m * p).collect();
        let (send, receive) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            use rayon::prelude::*;
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(2)
                .build()
                .unwrap();
            let poses: Vec<_> = pool.install(|| {
                (0..6)
                    .into_par_iter()
                    .map(|_| loaded.register(&source, None, &s).unwrap().t_target_source)
                    .collect()
            });
            let _ = send.send(poses);
        });
        let poses = receive
            .recv_timeout(std::time::Duration::from_secs(600))
            .expect("six registrations through a loaded model did not return in 10 minutes");
        for pose in &poses {
            assert_eq!(*pose, poses[0]);
        }
        let (rot, tr) = crate::geometry::se3::pose_errors(&poses[0], &m.inverse());
        assert!(rot < 0.5 && tr < 0.005, "{rot}°, {tr}");
    }
}
