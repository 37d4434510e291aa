//! `sdfreg`: the command-line front end. Converts flags and files, forwards to sdfreg-core.
//! Exit codes: 0 success, 2 bad input or failure (one line on stderr naming the problem),
//! 3 `batch` finished but some pairs failed (their errors are in its output).

mod align;
mod args;
mod batch;
mod eval;
mod output;

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{bail, Context, Result};
use clap::Parser;
use indicatif::{ProgressBar, ProgressStyle};
use nalgebra::{Isometry3, Matrix4, Point3, Translation3, UnitQuaternion, Vector3};
use rand::SeedableRng;
use sdfreg_core::geometry::mesh::sample_surface;
use sdfreg_core::geometry::se3::{isometry_from_matrix, pose_errors};
use sdfreg_core::io::{
    read_mesh, read_point_cloud, read_point_cloud_dropping_non_finite, write_mesh,
    write_moved_point_cloud, Fields, Format,
};
use sdfreg_core::{
    register_with_progress, MeshModel, RegisterSettings, Registration, Role, SdfModel, Stage,
};

use output::{matrix_text, registration_json, summary_line};

use args::{
    Cli, Command, DemoArgs, FitArgs, FitnessArgs, InputArgs, MeshArgs, RegisterArgs, TrackArgs,
    TransformArgs,
};

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Register(a) => cmd_register(a),
        Command::Fit(a) => cmd_fit(a),
        Command::Mesh(a) => cmd_mesh(a),
        Command::Track(a) => cmd_track(a),
        Command::Batch(a) => batch::run(a),
        Command::Demo(a) => cmd_demo(a),
        Command::Eval(a) => eval::run(a),
        Command::Align(a) => align::run(a),
        Command::Fitness(a) => cmd_fitness(a),
        Command::Transform(a) => cmd_transform(a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // One line: the error and each cause that adds something (an I/O error's cause is
            // often already in its message).
            let mut line = e.to_string();
            for cause in e.chain().skip(1) {
                let text = cause.to_string();
                if !line.contains(&text) {
                    line = format!("{line}: {text}");
                }
            }
            eprintln!("sdfreg: {}", line.replace('\n', " "));
            if e.is::<batch::SomeFailed>() || e.is::<align::SomeLeftOut>() {
                ExitCode::from(3)
            } else {
                ExitCode::from(2)
            }
        }
    }
}

/// A progress bar on stderr when it is a terminal; hidden otherwise.
pub fn progress_bar(len: u64) -> ProgressBar {
    if !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(len);
    bar.set_style(
        ProgressStyle::with_template("{spinner} {msg:24} [{bar:30}] {pos}/{len} {elapsed}")
            .unwrap()
            .progress_chars("=> "),
    );
    bar
}

/// Registers with a progress bar over the pre-fit and the alternations.
pub fn register_with_bar(
    source: &[Point3<f64>],
    target: &[Point3<f64>],
    init: Option<&Isometry3<f64>>,
    settings: &RegisterSettings,
) -> Result<Registration> {
    let alternations = settings.coarse_to_fine.alternations;
    let total = (settings.fit.prefit_steps + alternations * settings.fit.refine_steps) as u64;
    let bar = progress_bar(total);
    let prefit = settings.fit.prefit_steps;
    let refine = settings.fit.refine_steps;
    let report = |stage: Stage| match stage {
        Stage::Prefit(done, _) => {
            bar.set_message("fitting the target SDF");
            bar.set_position(done as u64);
        }
        Stage::Multistart => bar.set_message("multi-start"),
        Stage::Alternation(k, _) => {
            bar.set_message("coarse-to-fine");
            bar.set_position((prefit + k * refine) as u64);
        }
        Stage::Final => bar.set_message("final LM"),
        _ => {}
    };
    let r = register_with_progress(source, target, init, settings, &report);
    bar.finish_and_clear();
    Ok(r?)
}

fn refuse_overwrite(out: &Path, inputs: &[&Path], force: bool) -> Result<()> {
    for input in inputs {
        if same_file(out, input) {
            bail!(
                "{}: refusing to write the output over an input",
                out.display()
            );
        }
    }
    if out.exists() && !force {
        bail!("{}: exists; pass --force to overwrite", out.display());
    }
    Ok(())
}

fn same_file(a: &Path, b: &Path) -> bool {
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(x), Ok(y)) => x == y,
        _ => a == b,
    }
}

fn read_matrix(path: &Path) -> Result<Isometry3<f64>> {
    let m = read_matrix4(path)?;
    isometry_from_matrix(&m).with_context(|| {
        format!(
            "{}: the matrix is not a rigid transform (its 3×3 block must be a rotation, its last row 0 0 0 1)",
            path.display()
        )
    })
}

/// A similarity `[s R | t]` from a text file (for `--init` with `--scale`): its rigid part and
/// `s`.
fn read_similarity(path: &Path) -> Result<(Isometry3<f64>, f64)> {
    let m = read_matrix4(path)?;
    sdfreg_core::geometry::se3::similarity_from_matrix(&m).with_context(|| {
        format!(
            "{}: the matrix is not a similarity (its 3×3 block must be a positive scale times a rotation, its last row 0 0 0 1)",
            path.display()
        )
    })
}

/// The 16 numbers of a 4×4 matrix in a text file (12: the last row is `0 0 0 1`).
fn read_matrix4(path: &Path) -> Result<Matrix4<f64>> {
    let text = std::fs::read_to_string(path).with_context(|| format!("{}", path.display()))?;
    let values: Vec<f64> = text
        .split(|c: char| c.is_whitespace() || c == ',' || c == '[' || c == ']')
        .filter(|s| !s.is_empty())
        .map(|s| {
            s.parse::<f64>().map_err(|_| {
                anyhow::anyhow!(
                    "{}: {s:?} is not a number (expected 16 numbers, a 4×4 matrix)",
                    path.display()
                )
            })
        })
        .collect::<Result<_>>()?;
    if values.len() != 16 && values.len() != 12 {
        bail!(
            "{}: expected a 4×4 matrix (16 numbers), found {} numbers",
            path.display(),
            values.len()
        );
    }
    Ok(Matrix4::from_fn(|r, c| {
        if r < 3 || values.len() == 16 {
            values[r * 4 + c]
        } else if c == 3 {
            1.0
        } else {
            0.0
        }
    }))
}

/// Reads a cloud as `input` asks: a mesh's surface sampled (seeded by `seed`), or the points
/// with non-finite ones dropped.
fn read_cloud(path: &Path, input: &InputArgs, seed: u64) -> Result<Vec<Point3<f64>>> {
    if let Some(n) = input.surface_points {
        if Format::of(path)? == Format::Ply {
            let (vertices, triangles) = read_mesh(path)?;
            if !triangles.is_empty() {
                let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
                let points = sample_surface(&vertices, &triangles, n.max(1), &mut rng)
                    .with_context(|| format!("{}: the faces have no area", path.display()))?;
                eprintln!(
                    "sdfreg: {}: {} points sampled on {} triangles",
                    path.display(),
                    points.len(),
                    triangles.len()
                );
                return Ok(points);
            }
        }
    }
    let points = if input.drop_non_finite {
        let (points, dropped) = read_point_cloud_dropping_non_finite(path)?;
        say_dropped(&path.display().to_string(), dropped, points.len() + dropped);
        points
    } else {
        read_point_cloud(path)?
    };
    say_left_out(&path.display().to_string(), &points);
    Ok(points)
}

/// Says on stderr how many of `name`'s `total` points `--drop-non-finite` dropped, if any.
fn say_dropped(name: &str, dropped: usize, total: usize) {
    if dropped > 0 {
        eprintln!(
            "sdfreg: {name}: dropped {dropped} of {total} points with a NaN or infinite coordinate"
        );
    }
}

/// Says on stderr which of `name`'s points the registration will leave out (a scanner's
/// missing returns at the origin, stray returns far off).
fn say_left_out(name: &str, points: &[Point3<f64>]) {
    let left_out = sdfreg_core::geometry::cloud::LeftOut::of(points);
    for message in left_out.messages(points.len()) {
        eprintln!("sdfreg: {name}: {message}");
    }
}

/// A mesh's vertices and triangles (indices into the vertices).
type Mesh = (Vec<Point3<f64>>, Vec<[usize; 3]>);

/// The mesh of `--exact-mesh`: [`read_mesh`], refusing a file without faces.
fn read_exact_mesh(path: &Path) -> Result<Mesh> {
    let (vertices, triangles) = read_mesh(path)?;
    if triangles.is_empty() {
        bail!(
            "{}: --exact-mesh needs a mesh, but the file has no faces",
            path.display()
        );
    }
    Ok((vertices, triangles))
}

/// Whether `path` names a model file (`.sdfm`).
fn is_model(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("sdfm"))
}

/// `e` with the file it is about named, when it is about the source or the target cloud.
fn name_cloud(e: anyhow::Error, source: &Path, target: &Path) -> anyhow::Error {
    let role = e
        .downcast_ref::<sdfreg_core::Error>()
        .and_then(|e| e.role());
    match role {
        Some(Role::Source) => e.context(source.display().to_string()),
        Some(Role::Target) => e.context(target.display().to_string()),
        None => e,
    }
}

fn cmd_fit(a: FitArgs) -> Result<()> {
    refuse_overwrite(&a.output, &[a.target.as_path()], a.force)?;
    let target = read_cloud(&a.target, &a.input, a.common.seed)?;
    let settings = a.common.settings()?;
    let bar = progress_bar(settings.fit.model_prefit_steps as u64);
    bar.set_message("fitting the target SDF");
    let report = |stage: Stage| {
        if let Stage::Prefit(done, total) = stage {
            bar.set_length(total as u64);
            bar.set_position(done as u64);
        }
    };
    let start = std::time::Instant::now();
    let model = SdfModel::fit_with_progress(&target, &settings, &report).map_err(|e| {
        a.common
            .name_flag(name_cloud(e.into(), &a.target, &a.target))
    })?;
    let fit_time = start.elapsed();
    bar.finish_and_clear();
    model.save(&a.output)?;
    // How well Φ fits the target points: |Φ| there, in the target's units.
    let points = model.target_points();
    let mut d: Vec<f64> = model.distance(&points).iter().map(|v| v.abs()).collect();
    d.sort_by(f64::total_cmp);
    let rms = (d.iter().map(|v| v * v).sum::<f64>() / d.len() as f64).sqrt();
    let kind = match model.voxel() {
        Some(v) => format!(
            "local Φ ({} corrections, voxel {v:.3e})",
            model.local_parameters()
        ),
        None => "global Φ".to_string(),
    };
    eprintln!(
        "sdfreg: {}: fitted {} target points in {:.0} ms, {kind}; |Φ| on them: median {:.3e}, RMS {:.3e}, 95 % {:.3e} (target units, extent {:.3e})",
        a.output.display(),
        points.len(),
        fit_time.as_secs_f64() * 1e3,
        d[d.len() / 2],
        rms,
        d[(d.len() * 95 / 100).min(d.len() - 1)],
        model.normalization().scale,
    );
    Ok(())
}

fn cmd_fitness(a: FitnessArgs) -> Result<()> {
    if let Some(out) = &a.output {
        refuse_overwrite(out, &[a.source.as_path(), a.target.as_path()], a.force)?;
    }
    let transformation = match &a.transformation {
        Some(path) => read_transformation(path)?,
        None => Matrix4::identity(),
    };
    let source = read_cloud(&a.source, &a.input, a.seed)?;
    let evaluated = if a.exact_mesh {
        let (vertices, triangles) = read_exact_mesh(&a.target)?;
        let settings = sdfreg_core::RegisterSettings::default();
        let mesh = MeshModel::new(&vertices, &triangles, &settings)
            .with_context(|| a.target.display().to_string())?;
        mesh.evaluate_registration(&source, &transformation, a.max_distance)
    } else if is_model(&a.target) {
        SdfModel::load(&a.target)?.evaluate_registration(&source, &transformation, a.max_distance)
    } else {
        let target = read_cloud(&a.target, &a.input, a.seed)?;
        sdfreg_core::evaluate_registration(&source, &target, &transformation, a.max_distance)
    };
    let e = evaluated.map_err(|e| match (&e, &a.transformation) {
        (sdfreg_core::Error::InvalidSetting { .. }, _) => {
            anyhow::Error::new(e).context(format!("--max-distance {}", args::shown(a.max_distance)))
        }
        (sdfreg_core::Error::InvalidTransformation, Some(path)) => {
            anyhow::Error::new(e).context(path.display().to_string())
        }
        _ => name_cloud(e.into(), &a.source, &a.target),
    })?;
    println!(
        "fitness {:.6} ({} of {} source points within {}), inlier RMSE {:.6e}",
        e.fitness,
        e.inliers,
        e.source_points,
        args::shown(e.max_distance),
        e.inlier_rmse
    );
    if let Some(out) = &a.output {
        let mut json = evaluation_json(&e);
        json["points_left_out"] =
            serde_json::json!({"source": e.source_left_out, "target": e.target_left_out});
        std::fs::write(out, serde_json::to_string_pretty(&json)? + "\n")
            .with_context(|| out.display().to_string())?;
    }
    Ok(())
}

/// An [`sdfreg_core::Evaluation`]'s figures as JSON (`fitness`, `inlier_rmse`, `inliers`,
/// `source_points`, `max_distance`): `fitness --output` and each scan of `align --max-distance`.
fn evaluation_json(e: &sdfreg_core::Evaluation) -> serde_json::Value {
    serde_json::json!({
        "fitness": e.fitness,
        "inlier_rmse": e.inlier_rmse,
        "inliers": e.inliers,
        "source_points": e.source_points,
        "max_distance": e.max_distance,
    })
}

/// A 4×4 mapping source into target: `register --output`'s JSON (its `transformation`) when the
/// file ends in `.json`, else a text file of 16 numbers ([`read_matrix4`]).
fn read_transformation(path: &Path) -> Result<Matrix4<f64>> {
    match read_json(path)? {
        Some((_, json)) => transformation_in(path, &json),
        None => read_matrix4(path),
    }
}

/// The text of `path` and its JSON when the file ends in `.json`, else `None`.
fn read_json(path: &Path) -> Result<Option<(String, serde_json::Value)>> {
    if !path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("json"))
    {
        return Ok(None);
    }
    let text = std::fs::read_to_string(path).with_context(|| path.display().to_string())?;
    let json: serde_json::Value =
        serde_json::from_str(&text).with_context(|| format!("{}: not JSON", path.display()))?;
    Ok(Some((text, json)))
}

/// The `transformation` of `register --output`'s JSON (`json`, read from `path`).
fn transformation_in(path: &Path, json: &serde_json::Value) -> Result<Matrix4<f64>> {
    match sdfreg_core::geometry::se3::matrix_from_rows(&json["transformation"]) {
        Some(m) => Ok(m),
        None => bail!(
            "{}: expected a `transformation` of 4 rows of 4 numbers (as `sdfreg register --output \
             FILE.json` writes it)",
            path.display()
        ),
    }
}

/// Whether `json` is a poses file's (`sdfreg align --output`: a `scans` list and no top-level
/// `transformation`).
fn is_poses_file(json: &serde_json::Value) -> bool {
    json.get("transformation").is_none() && json.get("scans").is_some()
}

/// The 4×4 of a scan in the poses file `path` (its `text`, and its JSON `poses`): scan `scan`
/// when given, else the one whose `file` is `input` (the same file, however spelled); refused by
/// name when there is none, more than one (an E57 file's scans: name one with --scan) or it was
/// left out.
fn pose_of_scan(
    path: &Path,
    text: &str,
    poses: &serde_json::Value,
    input: &Path,
    scan: Option<usize>,
) -> Result<Matrix4<f64>> {
    let checked = sdfreg_core::views::poses_file::read_poses(text.as_bytes(), path)?;
    let files: Vec<&str> = poses["scans"]
        .as_array()
        .map(|s| s.iter().map(|v| v["file"].as_str().unwrap_or("")).collect())
        .unwrap_or_default();
    let k = match scan {
        Some(k) if k < checked.len() => k,
        Some(k) => bail!(
            "--scan {k}: {} holds {} scans (0 to {})",
            path.display(),
            checked.len(),
            checked.len().saturating_sub(1)
        ),
        None => {
            let hits: Vec<usize> = (0..files.len())
                .filter(|&k| same_file(Path::new(files[k]), input))
                .collect();
            match hits[..] {
                [k] => k,
                [] => bail!(
                    "{}: no scan of {} is {}; name one with --scan K",
                    path.display(),
                    path.display(),
                    input.display()
                ),
                _ => bail!(
                    "{}: {} holds {} of its scans; name one with --scan K",
                    path.display(),
                    input.display(),
                    hits.len()
                ),
            }
        }
    };
    if poses["scans"][k].get("scan").is_some() {
        bail!(
            "{}: scan {k} is one of the scans of the E57 file {}, which is moved as a whole; `sdfreg align --aligned FILE.e57` writes its scans posed",
            path.display(),
            files.get(k).copied().unwrap_or("")
        );
    }
    match checked[k] {
        Some(pose) => Ok(pose.to_homogeneous()),
        None => bail!(
            "{}: scan {k} ({}) was left out of the alignment: it has no transformation",
            path.display(),
            files.get(k).copied().unwrap_or("")
        ),
    }
}

/// `sdfreg transform`: INPUT moved by the transformation (or its inverse) to OUTPUT.
fn cmd_transform(a: TransformArgs) -> Result<()> {
    refuse_overwrite(&a.output, &[a.input.as_path()], a.force)?;
    let path = &a.transformation;
    let m = match read_json(path)? {
        Some((text, json)) if is_poses_file(&json) => {
            pose_of_scan(path, &text, &json, &a.input, a.scan)?
        }
        _ if a.scan.is_some() => bail!(
            "--scan: {} is not a poses file (`sdfreg align --output`)",
            path.display()
        ),
        Some((_, json)) => transformation_in(path, &json)?,
        None => read_matrix4(path)?,
    };
    let (rigid, scale) = sdfreg_core::geometry::se3::similarity_from_matrix(&m).with_context(|| {
        format!(
            "{}: the matrix is not a similarity (its 3×3 block must be a positive scale times a rotation, its last row 0 0 0 1)",
            a.transformation.display()
        )
    })?;
    let mut motion = nalgebra::Similarity3::from_isometry(rigid, scale);
    if a.inverse {
        motion = motion.inverse();
    }
    let moved = write_moved_point_cloud(&a.input, &a.output, &motion)?;
    let kept = match &moved.fields {
        Fields::Kept => "every other field kept".to_string(),
        Fields::CoordinatesOnly(why) => why.clone(),
    };
    eprintln!(
        "sdfreg: {}: {} points of {} moved ({} left in place: missing returns at the origin, non-finite); {kept}",
        a.output.display(),
        moved.points - moved.left_in_place,
        a.input.display(),
        moved.left_in_place
    );
    Ok(())
}

fn cmd_mesh(a: MeshArgs) -> Result<()> {
    refuse_overwrite(&a.output, &[a.model.as_path()], a.force)?;
    let model = SdfModel::load(&a.model)?;
    let (vertices, triangles) = model.mesh(a.resolution)?;
    write_mesh(&a.output, &vertices, &triangles)?;
    eprintln!(
        "sdfreg: {}: {} vertices, {} triangles (resolution {})",
        a.output.display(),
        vertices.len(),
        triangles.len(),
        a.resolution
    );
    Ok(())
}

fn cmd_track(a: TrackArgs) -> Result<()> {
    let mut inputs: Vec<&Path> = a.frames.iter().map(PathBuf::as_path).collect();
    inputs.push(&a.model);
    refuse_overwrite(&a.output, &inputs, a.force)?;
    let model = SdfModel::load(&a.model)?;
    let init = match &a.init {
        Some(path) => read_matrix(path)?,
        None => Isometry3::identity(),
    };
    let settings = a.common.settings_from("tracking")?;
    // A frame that cannot be read is reported in its line, like one that cannot be registered.
    let frames: Vec<Result<Vec<Point3<f64>>>> = a
        .frames
        .iter()
        .map(|f| read_cloud(f, &a.input, a.common.seed))
        .collect();
    let empty = Vec::new();
    let clouds: Vec<&[Point3<f64>]> = frames
        .iter()
        .map(|f| f.as_ref().map_or(empty.as_slice(), |c| c.as_slice()))
        .collect();
    let results = model.track(clouds, &init, &settings)?;
    let mut out = String::new();
    let mut failed = 0;
    for ((path, frame), r) in a.frames.iter().zip(&frames).zip(results) {
        let line = match (frame, r) {
            (Ok(_), Ok(r)) => serde_json::json!({
                "file": path,
                "transformation": output::matrix_rows(&r.matrix()),
                "fitness": r.fitness,
                "converged": r.converged,
                "time_ms": r.time.as_secs_f64() * 1e3,
            }),
            (Err(e), _) => serde_json::json!({"file": path, "error": format!("{e:#}")}),
            (Ok(_), Err(e)) => serde_json::json!({
                "file": path,
                "error": format!("{}: {e}", path.display()),
            }),
        };
        failed += usize::from(line.get("error").is_some());
        out += &(line.to_string() + "\n");
    }
    std::fs::write(&a.output, out).with_context(|| format!("{}", a.output.display()))?;
    if failed > 0 {
        bail!(
            "{failed} of {} frames failed (see {})",
            a.frames.len(),
            a.output.display()
        );
    }
    Ok(())
}

fn cmd_register(a: RegisterArgs) -> Result<()> {
    let inputs = [a.source.as_path(), a.target.as_path()];
    for out in [&a.output, &a.aligned].into_iter().flatten() {
        refuse_overwrite(out, &inputs, a.force)?;
    }
    let source = read_cloud(&a.source, &a.input, a.common.seed)?;
    let mut settings = a.common.settings()?;
    let init = match a.init.as_deref() {
        Some(path) if settings.scale.enabled => {
            let (pose, scale) = read_similarity(path)?;
            settings.scale.initial = Some(scale);
            Some(pose)
        }
        path => path.map(read_matrix).transpose()?,
    };
    let r = if a.exact_mesh {
        let (vertices, triangles) = read_exact_mesh(&a.target)?;
        let mesh = MeshModel::new(&vertices, &triangles, &settings)
            .map_err(|e| name_cloud(e.into(), &a.source, &a.target))?;
        mesh.register(&source, init.as_ref(), &settings)
            .map_err(anyhow::Error::from)
    } else if is_model(&a.target) {
        let model = SdfModel::load(&a.target)?;
        let r = if a.refine {
            model.register_refined(&source, init.as_ref(), &settings)
        } else {
            model.register(&source, init.as_ref(), &settings)
        }
        .map_err(anyhow::Error::from)?;
        // A full call would run again with a global Φ here; a stored model cannot.
        if model.fits_poorly(&r, &settings) {
            eprintln!(
                "sdfreg: warning: the source fits {:.3} of the local (scene) model {}; scans that overlap only in part register more reliably against a global one (`sdfreg fit --model global`)",
                r.fitness,
                a.target.display()
            );
        }
        Ok(r)
    } else {
        if a.refine {
            bail!("--refine: only with a model (.sdfm) as TARGET");
        }
        let target = read_cloud(&a.target, &a.input, a.common.seed)?;
        register_with_bar(&source, &target, init.as_ref(), &settings)
    }
    .map_err(|e| a.common.name_flag(name_cloud(e, &a.source, &a.target)))?;
    let m = r.matrix();
    match &a.output {
        Some(path)
            if path
                .extension()
                .is_some_and(|e| e.eq_ignore_ascii_case("json")) =>
        {
            let json = registration_json(&r);
            std::fs::write(path, serde_json::to_string_pretty(&json)? + "\n")
                .with_context(|| format!("{}", path.display()))?;
        }
        Some(path) => {
            std::fs::write(path, matrix_text(&m)).with_context(|| format!("{}", path.display()))?
        }
        None => print!("{}", matrix_text(&m)),
    }
    if let Some(path) = &a.aligned {
        let moved = write_moved_point_cloud(&a.source, path, &r.similarity())?;
        if let Fields::CoordinatesOnly(why) = &moved.fields {
            eprintln!("sdfreg: --aligned: {why}; the source's other fields are kept when it has the source's format");
        }
    }
    for f in &r.degeneracy.free {
        eprintln!(
            "sdfreg: warning: the clouds do not determine the {f}; the pose along it is arbitrary"
        );
    }
    if r.degeneracy.scale_free() {
        eprintln!(
            "sdfreg: warning: the clouds do not determine the scale (relative eigenvalue {:.1e}: a flat or featureless overlap looks the same at every size); it is arbitrary",
            r.degeneracy.scale_relative_eigenvalue.unwrap_or(0.0)
        );
    }
    eprintln!("sdfreg: {}", summary_line(&r));
    Ok(())
}

/// The demo's pair as `dir`/{source.ply, target.ply, gt.txt}; refuses to overwrite any of them.
fn write_demo_pair(
    dir: &std::path::Path,
    source: &[Point3<f64>],
    target: &[Point3<f64>],
    truth: &Isometry3<f64>,
) -> Result<()> {
    let files = ["source.ply", "target.ply", "gt.txt"].map(|f| dir.join(f));
    if let Some(existing) = files.iter().find(|f| f.exists()) {
        bail!(
            "{}: exists; the demo does not overwrite it (choose another --write-pair folder)",
            existing.display()
        );
    }
    std::fs::create_dir_all(dir).with_context(|| format!("{}", dir.display()))?;
    sdfreg_core::io::write_point_cloud(&files[0], source)?;
    sdfreg_core::io::write_point_cloud(&files[1], target)?;
    std::fs::write(&files[2], matrix_text(&truth.to_homogeneous()))
        .with_context(|| format!("{}", files[2].display()))?;
    println!("the pair written to {}", dir.display());
    Ok(())
}

fn cmd_demo(a: DemoArgs) -> Result<()> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(a.common.seed);
    let target = sdfreg_core::sim::shapes::blob(a.points.max(10), &mut rng);
    let axis = nalgebra::Unit::new_normalize(Vector3::new(1.0, 2.0, -1.5));
    let truth_motion = Isometry3::from_parts(
        Translation3::new(0.3, -0.2, 0.25),
        UnitQuaternion::from_axis_angle(&axis, a.angle.to_radians()),
    );
    let source: Vec<Point3<f64>> = target.iter().map(|p| truth_motion * p).collect();
    let truth = truth_motion.inverse();
    println!(
        "sdfreg demo: a {}-point procedural blob against a copy moved by {}° and {:.3} units",
        target.len(),
        a.angle,
        truth_motion.translation.vector.norm()
    );
    if let Some(dir) = &a.write_pair {
        write_demo_pair(dir, &source, &target, &truth)?;
    }
    let r = register_with_bar(&source, &target, None, &a.common.settings()?)?;
    let (re, te) = pose_errors(&r.t_target_source, &truth);
    print!("estimated t_target_source:\n{}", matrix_text(&r.matrix()));
    println!("rotation error {re:.3}°, translation error {te:.5} (shape ≈ 1.1 units across)");
    println!("{}", summary_line(&r));
    if re > 5.0 {
        bail!("demo registration failed: rotation error {re:.2}° exceeds 5°");
    }
    Ok(())
}
