// crates/sdfreg-core/examples/learn_init.rs: learns Φ's initialisation
// (sdfreg_core::field::learned_init) by Reptile on procedural objects, or compares fits from
// two initialisations.
//
//   cargo run --release -p sdfreg-core --example learn_init -- --out FILE
//       [--iterations 1000] [--inner-steps 100] [--step 0.5] [--seed 7]
//   cargo run --release -p sdfreg-core --example learn_init -- --compare [--with FILE]
//       [--shapes DIR]
//
// --out writes the safetensors file `field/learned_init.rs` reads; the shipped one was made with
// the defaults. --compare fits the same objects (36 fresh procedural ones, or every .ply under
// DIR, each turned at random) from the sphere and from the learned initialisation (the shipped
// one, or FILE) and prints Φ's quality after 0-500 Adam steps of the pre-fit.
use nalgebra::{Point3, Rotation3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use sdfreg_core::field::learned_init::LearnedInit;
use sdfreg_core::fit::fitter::{FitQuality, SdfFitter};
use sdfreg_core::geometry::cloud::Normalization;
use sdfreg_core::sim::shapes::assembly;
use sdfreg_core::{FitSettings, MlpSettings};

/// Points of each object.
const POINTS: usize = 10_000;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let value = |name: &str| {
        args.iter()
            .position(|a| a == name)
            .and_then(|i| args.get(i + 1).cloned())
    };
    let number = |name: &str, default: f64| -> Result<f64, String> {
        value(name).map_or(Ok(default), |v| {
            v.parse().map_err(|_| format!("{name}: not a number: {v}"))
        })
    };
    let seed = number("--seed", 7.0)? as u64;
    if args.iter().any(|a| a == "--compare") {
        let learned = match value("--with") {
            Some(path) => LearnedInit::from_bytes(&std::fs::read(&path)?)
                .ok_or(format!("{path}: not a learned initialisation"))?,
            None => sdfreg_core::field::learned_init::shipped()
                .ok_or("the crate's learned initialisation does not read")?
                .clone(),
        };
        return compare(value("--shapes"), &learned.params, seed);
    }
    let out = value("--out").ok_or("--out FILE or --compare")?;
    if std::path::Path::new(&out).exists() && !args.iter().any(|a| a == "--force") {
        return Err(format!("{out} exists (--force to overwrite)").into());
    }
    let iterations = number("--iterations", 1000.0)? as usize;
    let inner = number("--inner-steps", 100.0)? as usize;
    let step = number("--step", 0.5)? as f32;
    let init = learn(iterations, inner, step, seed);
    let notes = serde_json::json!({
        "method": "Reptile on sdfreg_core::sim::shapes::assembly objects, each turned at random",
        "iterations": iterations, "inner_steps": inner, "step": step, "seed": seed,
        "command": "cargo run --release -p sdfreg-core --example learn_init -- --out FILE",
    });
    std::fs::write(&out, init.to_bytes(notes))?;
    println!("wrote {out}");
    Ok(())
}

/// Reptile: from θ (the sphere's network at first), fit a new object for `inner` Adam steps
/// of the pre-fit and move θ by `step` (decreasing linearly to 0) towards the result.
fn learn(iterations: usize, inner: usize, step: f32, seed: u64) -> LearnedInit {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let sphere = MlpSettings::default();
    let fit = FitSettings::default();
    let first = turned(&assembly(POINTS, &mut rng), &mut rng);
    let mut theta = SdfFitter::new(first, &sphere, &fit, seed)
        .mlp()
        .params()
        .to_vec();
    for it in 0..iterations {
        let object = turned(&assembly(POINTS, &mut rng), &mut rng);
        let mut fitter = SdfFitter::new(object, &sphere, &fit, rng.random());
        fitter.restart_from(&theta).expect("one architecture");
        fitter.train(inner, fit.prefit_lr);
        let eps = step * (1.0 - it as f32 / iterations as f32);
        for (t, p) in theta.iter_mut().zip(fitter.mlp().params()) {
            *t += eps * (p - *t);
        }
        if (it + 1) % 100 == 0 {
            eprintln!("{} of {iterations} objects", it + 1);
        }
    }
    LearnedInit {
        width: sphere.width,
        depth: sphere.depth,
        beta: sphere.beta,
        params: theta,
    }
}

/// The fits' quality after 0, 50, …, 500 pre-fit steps from the sphere and from `learned`,
/// means over the objects.
fn compare(
    shapes: Option<String>,
    learned: &[f32],
    seed: u64,
) -> Result<(), Box<dyn std::error::Error>> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0xC0);
    let objects: Vec<Vec<Point3<f64>>> = match &shapes {
        Some(dir) => plys(dir)?
            .iter()
            .map(sdfreg_core::io::read_point_cloud)
            .collect::<Result<_, _>>()?,
        None => (0..36).map(|_| assembly(POINTS, &mut rng)).collect(),
    };
    let marks = [0, 50, 100, 150, 200, 250, 500];
    let mut sums = [[FitQuality::default(); 7]; 2];
    let fit = FitSettings::default();
    for object in &objects {
        let unit = turned(object, &mut rng);
        for (k, from_learned) in [false, true].into_iter().enumerate() {
            let mut fitter = SdfFitter::new(unit.clone(), &MlpSettings::default(), &fit, seed);
            if from_learned {
                fitter.restart_from(learned).ok_or("another architecture")?;
            }
            let mut done = 0;
            for (m, &steps) in marks.iter().enumerate() {
                fitter.train(steps - done, fit.prefit_lr);
                done = steps;
                let q = fitter.quality(2000, m as u64);
                sums[k][m].on_target += q.on_target / objects.len() as f64;
                sums[k][m].near_target += q.near_target / objects.len() as f64;
            }
        }
    }
    println!(
        "{} objects ({}); mean |Φ| on the target's points, mean error of |Φ| near them (normalised units)",
        objects.len(),
        shapes.as_deref().unwrap_or("procedural")
    );
    println!("| pre-fit steps | sphere on | sphere near | learned on | learned near |");
    println!("|---|---|---|---|---|");
    for (m, steps) in marks.iter().enumerate() {
        let (s, l) = (sums[0][m], sums[1][m]);
        println!(
            "| {steps} | {:.5} | {:.5} | {:.5} | {:.5} |",
            s.on_target, s.near_target, l.on_target, l.near_target
        );
    }
    Ok(())
}

/// Every .ply under `dir`, sorted.
fn plys(dir: &str) -> std::io::Result<Vec<std::path::PathBuf>> {
    let (mut out, mut stack) = (Vec::new(), vec![std::path::PathBuf::from(dir)]);
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(d)? {
            let p = entry?.path();
            if p.is_dir() {
                stack.push(p);
            } else if p.extension().is_some_and(|x| x == "ply") {
                out.push(p);
            }
        }
    }
    out.sort();
    Ok(out)
}

/// `object` turned at random, in its unit frame (f32), at most [`POINTS`] of its points.
fn turned(object: &[Point3<f64>], rng: &mut ChaCha8Rng) -> Vec<[f32; 3]> {
    let axis = Vector3::<f64>::from_fn(|_, _| StandardNormal.sample(rng));
    let turn = Rotation3::new(axis.normalize() * rng.random_range(0.0..std::f64::consts::PI));
    let moved: Vec<Point3<f64>> = object.iter().map(|p| turn * p).collect();
    let norm = Normalization::from_target(&moved).expect("an object of several points");
    (0..POINTS.min(moved.len()))
        .map(|_| norm.to_unit(&moved[rng.random_range(0..moved.len())]))
        .collect()
}
