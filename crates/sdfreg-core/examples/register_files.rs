// crates/sdfreg-core/examples/register_files.rs: cargo run -p sdfreg-core --example register_files
use sdfreg_core::{io::read_point_cloud, register, RegisterSettings};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let source = read_point_cloud("source.ply")?;
    let target = read_point_cloud("target.ply")?;
    let result = register(&source, &target, None, &RegisterSettings::default())?;
    let t_target_source = result.t_target_source; // nalgebra::Isometry3<f64>: source into target
    println!("{}", t_target_source.to_homogeneous());
    println!("fitness {:.3}, {:?}", result.fitness, result.time);
    Ok(())
}
