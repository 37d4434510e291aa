//! Criterion benches of the kernels and of a full registration, on procedural shapes.
//! Run: `cargo bench --bench register` (add `-- <filter>` for one group).

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use sdfreg_core::field::mlp::{Mlp, MlpSettings};
use sdfreg_core::fit::fitter::SdfFitter;
use sdfreg_core::fit::settings::FitSettings;
use sdfreg_core::sim::shapes;
use sdfreg_core::solve::lm::{Kernel, Lm, LmSettings};
use sdfreg_core::{register, RegisterSettings};

fn unit_points(n: usize) -> Vec<[f32; 3]> {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    shapes::blob(n, &mut rng)
        .iter()
        .map(|p| [p.x as f32 * 0.8, p.y as f32 * 0.8, p.z as f32 * 0.8])
        .collect()
}

fn mlp(c: &mut Criterion) {
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let net = Mlp::new(&MlpSettings::default(), &mut rng);
    let pts = unit_points(8192);
    let mut g = c.benchmark_group("mlp");
    g.throughput(Throughput::Elements(pts.len() as u64));
    g.bench_function("value_and_gradient_8192", |b| {
        b.iter(|| net.eval(&pts, true))
    });
    g.bench_function("value_8192", |b| b.iter(|| net.eval(&pts, false)));
    let block = &pts[..sdfreg_core::field::BLOCK];
    let mut ws = net.workspace();
    let mut grad = vec![0.0f32; net.num_params()];
    let dphi = vec![0.1f32; block.len()];
    let dgrad = vec![[0.1f32; 3]; block.len()];
    g.throughput(Throughput::Elements(block.len() as u64));
    g.bench_function("forward_backward_block_single_thread", |b| {
        b.iter(|| {
            net.forward_block(block, true, &mut ws);
            net.backward_block(&mut ws, &dphi, &dgrad, &mut grad);
        })
    });
    g.finish();
}

fn fit_and_lm(c: &mut Criterion) {
    let target = unit_points(1024);
    let settings = FitSettings::default();
    let mut fit = SdfFitter::new(target.clone(), &MlpSettings::default(), &settings, 3);
    fit.train(100, 2e-3);
    let mut g = c.benchmark_group("fit");
    g.throughput(Throughput::Elements(
        (settings.batch_queries + settings.batch_surface) as u64,
    ));
    g.bench_function("adam_step", |b| b.iter(|| fit.train(1, 1e-3)));
    let moved: Vec<[f32; 3]> = target
        .iter()
        .map(|p| [p[0] + 0.01, p[1], p[2] - 0.02])
        .collect();
    let mut fit_src = fit.clone();
    fit_src.add_source_queries(&moved);
    g.bench_function("adam_step_with_source_queries", |b| {
        b.iter(|| fit_src.train(1, 1e-3))
    });
    g.finish();
    let source: Vec<Point3<f64>> = target
        .iter()
        .map(|p| Point3::new(p[0] as f64, p[1] as f64, p[2] as f64))
        .collect();
    let mut g = c.benchmark_group("lm");
    g.throughput(Throughput::Elements(source.len() as u64));
    let pose = Isometry3::from_parts(
        Translation3::new(0.01, 0.0, -0.01),
        UnitQuaternion::from_scaled_axis(Vector3::new(0.02, 0.0, 0.01)),
    );
    g.bench_function("step_1024", |b| {
        b.iter(|| {
            let mut lm = Lm::new(pose, &LmSettings::default());
            lm.step(fit.mlp(), &source, Kernel::L2)
        })
    });
    g.finish();
}

fn full(c: &mut Criterion) {
    let mut g = c.benchmark_group("register");
    g.sample_size(10);
    for n in [1024usize, 10_000] {
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let target = shapes::blob(n, &mut rng);
        let motion = Isometry3::from_parts(
            Translation3::new(0.2, -0.1, 0.3),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.3, -0.4, 0.2)),
        );
        let source: Vec<Point3<f64>> = target.iter().map(|p| motion * p).collect();
        g.throughput(Throughput::Elements(n as u64));
        g.bench_with_input(BenchmarkId::new("pair", n), &n, |b, _| {
            b.iter(|| register(&source, &target, None, &RegisterSettings::default()).unwrap())
        });
    }
    g.finish();
}

criterion_group!(benches, mlp, fit_and_lm, full);
criterion_main!(benches);
