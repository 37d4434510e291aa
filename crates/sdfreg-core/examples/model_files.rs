// crates/sdfreg-core/examples/model_files.rs: cargo run -p sdfreg-core --example model_files
use sdfreg_core::{io::read_point_cloud, RegisterSettings, SdfModel};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let settings = RegisterSettings::default();
    let model = SdfModel::fit(&read_point_cloud("target.ply")?, &settings)?; // once
    model.save("target.sdfm")?; // SdfModel::load("target.sdfm")? later
    for scan in ["source.ply", "target.ply"] {
        let r = model.register(&read_point_cloud(scan)?, None, &settings)?; // Φ frozen
        println!("{scan}: fitness {:.3}\n{}", r.fitness, r.matrix());
    }
    Ok(())
}
