//! Command-line flags, turned into validated settings in one place.

use std::path::PathBuf;

use clap::{Args, Parser, Subcommand};
use sdfreg_core::{ModelKind, RegisterSettings, RobustMode};

/// Correspondence-free rigid point-cloud registration by a neural signed distance function.
#[derive(Parser, Debug)]
#[command(name = "sdfreg", version, about, long_about = None)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Register SOURCE onto TARGET (a cloud, or a model from `sdfreg fit`); print the 4×4
    /// transform mapping source into target.
    Register(RegisterArgs),
    /// Fit the SDF model of TARGET once and save it (.sdfm), to register many sources against.
    Fit(FitArgs),
    /// Write the zero level set of a model's SDF as a triangle mesh (.ply), to look at it.
    Mesh(MeshArgs),
    /// Register a sequence of frames against a model, each from the previous frame's pose; one
    /// JSON line per frame.
    Track(TrackArgs),
    /// Register many pairs listed in a CSV file on every core, one JSON line per pair;
    /// resumable.
    Batch(BatchArgs),
    /// Register a built-in procedural shape against a moved copy and print the errors.
    Demo(DemoArgs),
    /// Evaluate on the paper's ModelNet40 protocols over a folder of shapes.
    Eval(EvalArgs),
    /// Align many scans (views of one object or scene) into the frame of one of them, from no
    /// initial guesses; writes each scan's pose (poses.json), and on request one model and one
    /// mesh of them all.
    Align(AlignArgs),
    /// How well SOURCE, moved by a transformation, lies on TARGET at a distance in their units:
    /// the share of SOURCE's points within --max-distance of a TARGET point (fitness) and their
    /// RMS distance, as Open3D's evaluate_registration reports them; no registration is run.
    Fitness(FitnessArgs),
    /// Write INPUT moved by a 4×4 transformation to OUTPUT, each point's other fields (intensity,
    /// colour, classification, GPS time, normals turned) kept when OUTPUT has INPUT's format:
    /// a full-resolution scan placed by the pose found on a thinned copy, a scan placed by its
    /// pose in `align`'s poses.json.
    Transform(TransformArgs),
}

/// The robust kernel's modes (`RobustMode`), as flags name them.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum RobustFlag {
    /// Least squares throughout.
    Off,
    /// The robust kernel from the start (scans that overlap in part).
    On,
    /// Least squares, redone with the robust kernel when it fits poorly.
    Auto,
}

/// Settings shared by every command that registers.
#[derive(Args, Debug, Clone)]
pub struct Common {
    /// Start from a named preset: `default`, `scans` for scans known to overlap only in part
    /// (robust kernel from the start, multi-start tie 0.05), `views` (`scans` with an object's
    /// polish pass ending when its steps stop shrinking, against planes at the target's points; a scene's polish on 16384 source points; `align`'s default), `tracking` (warm-started frames: no multi-start,
    /// a few LM steps, a short polish; `track`'s default), or `learned` (an object's pre-fit of
    /// 150 steps from an initialisation learned on procedural objects: about 0.7 of the time of
    /// a full call; one of the bunny's six scan pairs lost). Other flags override it.
    #[arg(long, value_parser = clap::builder::PossibleValuesParser::new(RegisterSettings::PRESETS))]
    pub preset: Option<String>,
    /// Seed of every random choice (equal seeds give identical results).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Worker threads; 0 = one per core. Results do not depend on it.
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
    /// Coarse-to-fine alternations of SDF refinement and LM steps, for an object (a global Φ)
    /// [default: 10].
    #[arg(long)]
    pub alternations: Option<usize>,
    /// The same for a scene (a local Φ: `--model local`, or `auto` on a room or street)
    /// [default: 5].
    #[arg(long)]
    pub scene_alternations: Option<usize>,
    /// Adam steps of the SDF pre-fit of a full call, for an object (a global Φ) [default: 250].
    #[arg(long)]
    pub prefit_steps: Option<usize>,
    /// Adam steps of a stored model's pre-fit (`sdfreg fit`, `align`, `eval --via-model`), for
    /// an object (a global Φ): fitted once, registered against many times [default: 2000].
    #[arg(long)]
    pub model_prefit_steps: Option<usize>,
    /// The same for a scene (a local Φ, whose surface comes from the target's planes)
    /// [default: 200].
    #[arg(long)]
    pub scene_prefit_steps: Option<usize>,
    /// Adam steps of SDF refinement per alternation, for an object (a global Φ) [default: 10].
    #[arg(long)]
    pub refine_steps: Option<usize>,
    /// The same for a scene (a local Φ; a full call only) [default: 40].
    #[arg(long)]
    pub scene_refine_steps: Option<usize>,
    /// When the robust (Geman–McClure) kernel is used: `auto` (least squares, redone with the
    /// kernel when the result fits fewer than --robust-below-fitness of the source points, kept
    /// if it fits 1.3 times as many), `on` (from the start: partial overlap), `off`
    /// [default: the preset's, auto].
    #[arg(long, value_enum, conflicts_with = "robust")]
    pub robust_mode: Option<RobustFlag>,
    /// Same as --robust-mode on.
    #[arg(long)]
    pub robust: bool,
    /// A fixed robust kernel scale (fraction of the target's largest side) from the start.
    #[arg(long, conflicts_with_all = ["robust", "robust_mode"])]
    pub robust_scale: Option<f64>,
    /// With --robust-mode auto: the fitness below which the robust re-run is tried; 0 never
    /// [default: 0.35].
    #[arg(long)]
    pub robust_below_fitness: Option<f64>,
    /// With --robust-mode auto: the share of the source outside the target's coverage (beyond
    /// 10 target point spacings) above which the robust re-run is tried when the result also
    /// fits less than 1 minus it, kept if it fits more points; 1 never [default: 0.2].
    #[arg(long)]
    pub robust_outside_share: Option<f64>,
    /// Also start the multi-start shifted by ± this along each axis (fraction of the target's
    /// size) [default: 0.1].
    #[arg(long)]
    pub multistart_offset: Option<f64>,
    /// Multi-start finalists within this fraction of the best score are ties, won by the smallest
    /// rotation [default: the preset's, 0.25; scans 0.05].
    #[arg(long)]
    pub multistart_tie: Option<f64>,
    /// Skip the 24-rotation multi-start (centroid alignment only).
    #[arg(long)]
    pub no_multistart: bool,
    /// Source points the solver uses at most; larger sources are subsampled (seeded) [default: 4096].
    #[arg(long)]
    pub max_source_points: Option<usize>,
    /// Target points the SDF fit uses at most; larger targets are subsampled (seeded) [default: 100000].
    #[arg(long)]
    pub max_target_points: Option<usize>,
    /// A target cloud with at least this many times fewer points than the source (and at least
    /// half its size) is registered the other way round, the denser cloud as Φ's, and the
    /// result inverted (`stages.swapped` in the JSON); 0 never [default: 4].
    #[arg(long)]
    pub swap_ratio: Option<f64>,
    /// Kind of Φ: `global` (one MLP: objects), `local` (the MLP plus a sparse voxel grid of
    /// corrections near the target's points: rooms, streets), or `auto` (local when the
    /// target's largest side is at least 400 point spacings, `LocalSettings.auto_ratio`)
    /// [default: auto].
    #[arg(long = "model", id = "model_kind", value_name = "KIND",
          value_parser = clap::builder::PossibleValuesParser::new(ModelKind::NAMES))]
    pub model_kind: Option<String>,
    /// Voxel side of the local model, as a fraction of the target's largest side [default: the
    /// larger of 1/128 and 3 target point spacings].
    #[arg(long)]
    pub local_voxel: Option<f64>,
    /// Voxel side of the local model in the target's units (metres for a LiDAR scan), in place
    /// of --local-voxel; makes `--model auto` local.
    #[arg(long, value_name = "SIZE")]
    pub local_voxel_size: Option<f64>,
    /// Estimate a scale with the pose (similarity: millimetres against metres, an SfM
    /// reconstruction against a LiDAR map): the result is `[s R | t]`, and JSON gains `scale`.
    /// With --init, the matrix's 3×3 block gives the starting scale.
    #[arg(long)]
    pub scale: bool,
    /// With --scale: the scale (target units per source unit) stays within MIN and MAX
    /// [default: 0.1 to 10 times the unit factor, 1, 1000 or 0.001, that the clouds' extents
    /// point to].
    #[arg(long, num_args = 2, value_names = ["MIN", "MAX"], requires = "scale")]
    pub scale_range: Option<Vec<f64>>,
}

impl Common {
    /// The settings these flags ask for: the preset (`default` when none is named), then each
    /// flag given.
    pub fn settings(&self) -> anyhow::Result<RegisterSettings> {
        self.settings_from("default")
    }

    /// [`Common::settings`] with `preset` when no preset is named.
    pub fn settings_from(&self, preset: &str) -> anyhow::Result<RegisterSettings> {
        let name = self.preset.as_deref().unwrap_or(preset);
        let mut s = RegisterSettings::preset(name)
            .ok_or_else(|| anyhow::anyhow!("--preset: unknown preset {name:?}"))?;
        s.seed = self.seed;
        s.threads = self.threads;
        s.multistart.enabled &= !self.no_multistart;
        let flag = if self.robust {
            Some(RobustFlag::On)
        } else {
            self.robust_mode
        };
        match (flag, self.robust_scale) {
            (_, Some(scale)) => s.robust.mode = RobustMode::Fixed { scale },
            (Some(RobustFlag::Off), _) => s.robust.mode = RobustMode::Off,
            (Some(RobustFlag::On), _) => s.robust.mode = RobustMode::On,
            (Some(RobustFlag::Auto), _) => s.robust.mode = RobustMode::AUTO,
            (None, None) => {}
        }
        if let Some(f) = self.robust_outside_share {
            let RobustMode::Auto { outside_share, .. } = &mut s.robust.mode else {
                anyhow::bail!("--robust-outside-share: only with --robust-mode auto");
            };
            *outside_share = f;
        }
        if let Some(f) = self.robust_below_fitness {
            let RobustMode::Auto { below_fitness, .. } = &mut s.robust.mode else {
                anyhow::bail!("--robust-below-fitness: only with --robust-mode auto");
            };
            *below_fitness = f;
        }
        let set = |field: &mut usize, flag: Option<usize>| *field = flag.unwrap_or(*field);
        set(&mut s.coarse_to_fine.alternations, self.alternations);
        set(
            &mut s.coarse_to_fine.scene_alternations,
            self.scene_alternations,
        );
        set(&mut s.fit.local.prefit_steps, self.scene_prefit_steps);
        set(&mut s.fit.refine_steps, self.refine_steps);
        set(&mut s.fit.local.refine_steps, self.scene_refine_steps);
        set(&mut s.fit.prefit_steps, self.prefit_steps);
        set(&mut s.fit.model_prefit_steps, self.model_prefit_steps);
        set(&mut s.max_source_points, self.max_source_points);
        set(&mut s.max_target_points, self.max_target_points);
        s.swap_ratio = self.swap_ratio.unwrap_or(s.swap_ratio);
        s.multistart.offset = self.multistart_offset.unwrap_or(s.multistart.offset);
        s.multistart.tie = self.multistart_tie.unwrap_or(s.multistart.tie);
        if let Some(name) = &self.model_kind {
            s.fit.local.kind = ModelKind::from_name(name)
                .ok_or_else(|| anyhow::anyhow!("--model: unknown kind {name:?}"))?;
        }
        if let Some(v) = self.local_voxel {
            anyhow::ensure!(
                v > 0.0 && v <= 1.0,
                "--local-voxel: a fraction of the target's largest side, in (0, 1]; got {}",
                shown(v)
            );
            s.fit.local.cells = ((1.0 / v).round() as usize).max(1);
            s.fit.local.spacings = 0.0;
        }
        if let Some(v) = self.local_voxel_size {
            s.fit.local.voxel_size = Some(v);
        }
        s.scale.enabled |= self.scale;
        if let Some(range) = &self.scale_range {
            (s.scale.min, s.scale.max) = (Some(range[0]), Some(range[1]));
            s.scale.validate().map_err(|e| {
                anyhow::anyhow!("--scale-range {} {}: {e}", shown(range[0]), shown(range[1]))
            })?;
        }
        Ok(s)
    }
}

impl Common {
    /// `e` with the flag named that set the setting it is about (`--local-voxel` sets
    /// `fit.local.cells`), so the message says what to change on the command line.
    pub fn name_flag(&self, e: anyhow::Error) -> anyhow::Error {
        let setting = match e.downcast_ref::<sdfreg_core::Error>() {
            Some(sdfreg_core::Error::InvalidSetting { name, .. }) => *name,
            _ => return e,
        };
        match (setting, self.local_voxel, self.local_voxel_size) {
            ("fit.local.cells", Some(v), _) => e.context(format!("--local-voxel {}", shown(v))),
            ("fit.local.voxel_size", _, Some(v)) => {
                e.context(format!("--local-voxel-size {}", shown(v)))
            }
            _ => e,
        }
    }
}

/// A flag's number as a user would write it: plain in [10⁻⁴, 10⁶), else in exponent form
/// (`1e-300`, not 300 zeros).
pub fn shown(v: f64) -> String {
    if v == 0.0 || !v.is_finite() || (1e-4..1e6).contains(&v.abs()) {
        format!("{v}")
    } else {
        format!("{v:e}")
    }
}

/// How input clouds are read.
#[derive(Args, Debug, Clone)]
pub struct InputArgs {
    /// Drop points with a NaN or infinite coordinate (and say how many) instead of refusing the
    /// file: organised PCL clouds and range scanners mark missing returns that way.
    #[arg(long)]
    pub drop_non_finite: bool,
    /// A PLY input with faces (a mesh) is replaced by this many points sampled uniformly on its
    /// surface (seeded by --seed) instead of its vertices; clouds are read as they are.
    #[arg(long, value_name = "N")]
    pub surface_points: Option<usize>,
}

#[derive(Args, Debug)]
pub struct FitArgs {
    /// Cloud to model (.ply, .pcd, .las, .laz, .e57, .xyz, .txt, .csv).
    pub target: PathBuf,
    /// The model file to write (.sdfm).
    #[arg(long, short)]
    pub output: PathBuf,
    /// Overwrite --output if it exists.
    #[arg(long)]
    pub force: bool,
    #[command(flatten)]
    pub input: InputArgs,
    #[command(flatten)]
    pub common: Common,
}

#[derive(Args, Debug)]
pub struct MeshArgs {
    /// The model (.sdfm, from `sdfreg fit`).
    pub model: PathBuf,
    /// The mesh file to write (.ply).
    #[arg(long, short)]
    pub output: PathBuf,
    /// Grid cells along the target's largest side (4 to 1024).
    #[arg(long, default_value_t = 128)]
    pub resolution: usize,
    /// Overwrite --output if it exists.
    #[arg(long)]
    pub force: bool,
}

#[derive(Args, Debug)]
pub struct TrackArgs {
    /// The model (.sdfm, from `sdfreg fit`).
    pub model: PathBuf,
    /// The frames, in order (.ply, .pcd, .las, .laz, .e57, .xyz, .txt, .csv).
    #[arg(required = true)]
    pub frames: Vec<PathBuf>,
    /// Where to write one JSON line per frame (`file`, `transformation` mapping the frame into
    /// the model's frame, `fitness`, `converged`, `time_ms`; or `file` and `error`).
    #[arg(long, short)]
    pub output: PathBuf,
    /// The first frame's pose: a text file with a 4×4 matrix (frame into model) [default:
    /// identity].
    #[arg(long)]
    pub init: Option<PathBuf>,
    /// Overwrite --output if it exists.
    #[arg(long)]
    pub force: bool,
    #[command(flatten)]
    pub input: InputArgs,
    #[command(flatten)]
    pub common: Common,
}

#[derive(Args, Debug)]
pub struct RegisterArgs {
    /// Cloud to move (.ply, .pcd, .las, .laz, .e57, .xyz, .txt, .csv).
    pub source: PathBuf,
    /// Fixed cloud (.ply, .pcd, .las, .laz, .e57, .xyz, .txt, .csv), or a model written by `sdfreg fit` (.sdfm),
    /// registered against without fitting (Φ frozen; see --refine).
    pub target: PathBuf,
    /// With a model as TARGET: refine a private copy of its SDF with the moved source among its
    /// queries, as registering against the cloud does (slower, the same numbers as the cloud).
    #[arg(long)]
    pub refine: bool,
    /// TARGET is a mesh (.ply with faces) used as its own exact distance field (the distance to
    /// its triangles) instead of a fitted SDF: no fitting; for CAD models and reconstructions.
    #[arg(long, conflicts_with = "refine")]
    pub exact_mesh: bool,
    /// Write the result here instead of printing it: JSON when it ends in .json, else the 4×4 as text.
    #[arg(long, short)]
    pub output: Option<PathBuf>,
    /// Write the moved source cloud here (.ply, .pcd, .las, .laz, .e57 or text).
    #[arg(long)]
    pub aligned: Option<PathBuf>,
    /// Initial guess: a text file with a 4×4 matrix (source into target); skips the multi-start.
    #[arg(long)]
    pub init: Option<PathBuf>,
    #[command(flatten)]
    pub input: InputArgs,
    /// Overwrite --output / --aligned if they exist.
    #[arg(long)]
    pub force: bool,
    #[command(flatten)]
    pub common: Common,
}

#[derive(Args, Debug)]
pub struct BatchArgs {
    /// The pairs, one per row: `source,target[,init[,seed]]`. TARGET is a cloud or a model
    /// (.sdfm; loaded once, registered against with Φ frozen); INIT a 4×4 matrix file (source
    /// into target) or empty; SEED an integer or empty (--seed). Relative paths are relative to
    /// this file's folder. A first row `source,target,…` is a header; `#` starts a comment.
    pub pairs: PathBuf,
    /// Results, one JSON line per finished pair (`row`, `source`, `target`, `seed`, `ok`, then
    /// the registration as `register --output FILE.json` writes it, or `error`). If it exists,
    /// the batch resumes: rows already in it are skipped.
    #[arg(long, short)]
    pub output: PathBuf,
    /// Start --output afresh instead of resuming it.
    #[arg(long)]
    pub force: bool,
    #[command(flatten)]
    pub input: InputArgs,
    /// Settings of every pair; --threads is the number of pairs registered at once (0 = one
    /// per core), each on one thread.
    #[command(flatten)]
    pub common: Common,
}

#[derive(Args, Debug)]
pub struct AlignArgs {
    /// The scans (.ply, .pcd, .las, .laz, .e57, .xyz, .txt, .csv), each in its own frame; at
    /// least two. An E57 file that holds several scans gives each as a scan, in its own frame
    /// (the file's poses are not used), named FILE#k in messages and edges.
    #[arg(required = true)]
    pub scans: Vec<PathBuf>,
    /// Where to write the poses (JSON): per scan `file` (with `scan` and `name` for a scan of
    /// an E57 file), `transformation` (4×4, the scan's
    /// coordinates into the anchor's frame; null for a scan left out, with `left_out` saying
    /// why) and `fitness`; `edges` (each pair registered, its fitness, whether the pose graph
    /// kept it, with --seen-from its `in_free_space` share); `time_ms` and `stage_ms`.
    #[arg(long, short)]
    pub output: PathBuf,
    /// Also write one model of all the aligned scans (.sdfm). (`--model` is the kind of Φ, as
    /// for every command that fits one.)
    #[arg(long, value_name = "FILE")]
    pub save_model: Option<PathBuf>,
    /// Also write the zero level set of that model as a mesh (.ply).
    #[arg(long)]
    pub mesh: Option<PathBuf>,
    /// Also write the placed scans: as .e57, each as a scan of its own, its points as read and
    /// its pose into the anchor's frame (what scanning software reads as a registered
    /// campaign); in another format, all their points moved into the anchor's frame, as one
    /// cloud.
    #[arg(long, value_name = "FILE")]
    pub aligned: Option<PathBuf>,
    /// Grid cells along the largest side for --mesh (4 to 1024).
    #[arg(long, default_value_t = 256)]
    pub mesh_resolution: usize,
    /// The scan (0-based, in the order given, each scan of an E57 file counted) whose frame the
    /// poses map into.
    #[arg(long, default_value_t = 0)]
    pub anchor: usize,
    /// Approximate initial poses: a poses.json (its `scans[].transformation`, one per scan, in
    /// order; a turntable's angles, odometry) [default: none, every pair from nothing].
    #[arg(long)]
    pub init: Option<PathBuf>,
    /// Above 16 scans (each paired with its next 3), the pairs each scan joins once the pose
    /// graph has placed them: between scans that overlap and lie at least 5 kept edges apart
    /// (loop closures); 0 skips them.
    #[arg(long, default_value_t = 2)]
    pub closure_pairs: usize,
    /// Joint refinement rounds: each scan registered against one model of all the others (it
    /// did not help on the measured sets; see the guide's Many views page).
    #[arg(long, default_value_t = 0)]
    pub joint_rounds: usize,
    /// Iterations of the multi-view point-to-plane refinement after the pose graph (every pose
    /// at once, against the other scans' points where they overlap); 0 skips it. The poses the
    /// scans' own points agree on; off by default, as it did not bring the measured sets nearer
    /// their references (see the guide's Many views page). 30 is plenty.
    #[arg(long, default_value_t = 0)]
    pub consensus_iterations: usize,
    /// Where each scan was seen from, in its own frame: `origin` (a LiDAR or depth camera's
    /// scan in its sensor's frame), an axis (`+z`: a scanner far along +z, as the Stanford
    /// scans) or a direction `x,y,z`. A pair that puts more than --max-in-free-space of either
    /// scan where the other's sensor saw empty space is then no edge (a look-alike part laid
    /// onto another) [default: no such check].
    #[arg(long, value_name = "VIEW")]
    pub seen_from: Option<sdfreg_core::SeenFrom>,
    /// See --seen-from: the share of a scan's points (of those facing a return of the other).
    #[arg(long, default_value_t = 0.02)]
    pub max_in_free_space: f64,
    /// Also measure, with no reference, how well each aligned scan lies on the others: the
    /// share of its points within this distance of another scan's point, in the scans' units,
    /// and their RMS distance (as `sdfreg fitness`), written per scan as `evaluation` and
    /// summed up on stderr.
    #[arg(long, value_name = "DISTANCE")]
    pub max_distance: Option<f64>,
    /// Overwrite --output, --save-model and --mesh if they exist.
    #[arg(long)]
    pub force: bool,
    #[command(flatten)]
    pub input: InputArgs,
    /// The pairwise registrations' settings [default: --preset scans].
    #[command(flatten)]
    pub common: Common,
}

#[derive(Args, Debug)]
pub struct DemoArgs {
    /// Points in the procedural shape.
    #[arg(long, default_value_t = 1024)]
    pub points: usize,
    /// Rotation of the copy, degrees about a fixed oblique axis.
    #[arg(long, default_value_t = 40.0)]
    pub angle: f64,
    /// Also write the pair into this folder (made if missing) as source.ply, target.ply and
    /// gt.txt (the true 4×4, source into target), to try the other commands on; existing files
    /// are not overwritten.
    #[arg(long, value_name = "DIR")]
    pub write_pair: Option<PathBuf>,
    #[command(flatten)]
    pub common: Common,
}

#[derive(Args, Debug)]
pub struct EvalArgs {
    /// Folder searched recursively for .ply shapes (e.g. ../shared/data/modelnet40-half1).
    #[arg(long)]
    pub shapes: PathBuf,
    /// Comma-separated protocols: clean, noise, partial, density (the paper's), anyrot (uniform
    /// rotations), and each of the paper's with `-indep` (independently sampled source and
    /// target, e.g. clean-indep); `paper` for the paper's four, `all` for every rigid one;
    /// `scaled` and `scaled-indep` (the source scaled by U[0.5, 2]) register with --scale.
    #[arg(long, default_value = "all")]
    pub protocol: String,
    /// Pairs per protocol (shapes are used in turn).
    #[arg(long, default_value_t = 12)]
    pub pairs: usize,
    /// Keep every pair's numbers in this JSON file.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Write every pair here (PROTOCOL/NNN_SHAPE/{source.ply, target.ply, gt.txt} and
    /// pairs.json), so other programs can run on exactly the same pairs.
    #[arg(long)]
    pub write_pairs: Option<PathBuf>,
    /// Only make (and write) the pairs; register nothing.
    #[arg(long, requires = "write_pairs")]
    pub pairs_only: bool,
    /// Fit each pair's target once as a model (`sdfreg fit`) and register the source against it
    /// with Φ frozen; the table's times are then the registrations alone. Each pair also runs
    /// a full `register` call: below each protocol's row, the median fit time, the median full
    /// call and the registration against the model as a share of it.
    #[arg(long)]
    pub via_model: bool,
    /// Overwrite --json or --write-pairs output if it exists.
    #[arg(long)]
    pub force: bool,
    #[command(flatten)]
    pub common: Common,
}

#[derive(Args, Debug)]
pub struct FitnessArgs {
    /// The cloud to move (.ply, .pcd, .las, .laz, .e57, .xyz, .txt, .csv).
    pub source: PathBuf,
    /// What it is measured against, fixed: a cloud, a model (.sdfm: the target points it was
    /// fitted to), or with --exact-mesh a mesh.
    pub target: PathBuf,
    /// A source point is an inlier when its nearest target point is within this distance, in
    /// the clouds' units (metres for a LiDAR scan).
    #[arg(long, value_name = "DISTANCE")]
    pub max_distance: f64,
    /// TARGET is a mesh (.ply with faces): each source point's exact distance to its triangles
    /// instead of the distance to the nearest target point.
    #[arg(long)]
    pub exact_mesh: bool,
    /// The 4×4 mapping SOURCE into TARGET's frame: a text file of 16 numbers (what `register`
    /// prints), or `register --output`'s .json [default: identity, the clouds as they are].
    #[arg(long, short)]
    pub transformation: Option<PathBuf>,
    /// Also write the figures as JSON (`fitness`, `inlier_rmse`, `inliers`, `source_points`,
    /// `max_distance`, `points_left_out`).
    #[arg(long, short)]
    pub output: Option<PathBuf>,
    /// Overwrite --output if it exists.
    #[arg(long)]
    pub force: bool,
    /// Seed of --surface-points' sampling.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    #[command(flatten)]
    pub input: InputArgs,
}

#[derive(Args, Debug)]
pub struct TransformArgs {
    /// The cloud file to move (.ply, .pcd, .las, .laz, .e57, .xyz, .txt, .csv, .pts).
    pub input: PathBuf,
    /// Where to write it moved; in INPUT's format every other field is kept, in another the
    /// coordinates alone.
    pub output: PathBuf,
    /// The 4×4 `[s R | t]` mapping INPUT's coordinates into OUTPUT's: a text file of 16 numbers
    /// (what `register` prints), `register --output`'s .json, or `align --output`'s poses.json
    /// (the pose of the scan whose file is INPUT, into the anchor's frame).
    #[arg(long, short)]
    pub transformation: PathBuf,
    /// With a poses file: take its scan K (0-based, in the file's order) instead of the one whose
    /// file is INPUT.
    #[arg(long, value_name = "K")]
    pub scan: Option<usize>,
    /// Apply the inverse of --transformation (a target moved into its source's frame).
    #[arg(long)]
    pub inverse: bool,
    /// Overwrite OUTPUT if it exists.
    #[arg(long)]
    pub force: bool,
}
