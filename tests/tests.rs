//! Integration tests of sdfreg-core on procedural shapes (no data files needed).

mod common;
mod io;
mod layers;
mod model;
mod register;
mod scenes;
mod views;
