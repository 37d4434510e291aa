//! Beside the layers, procedural data for tests, benchmarks and demos: [`shapes`] (test
//! shapes) and [`lidar`] (a spinning multi-beam LiDAR ray-cast into a street or a room).

pub mod lidar;
pub mod shapes;
