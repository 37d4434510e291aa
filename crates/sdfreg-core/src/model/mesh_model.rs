//! A target mesh as a model: its exact distance field ([`crate::field::mesh::MeshField`]) and
//! points sampled on it, registered against without any fitting.

use nalgebra::{Isometry3, Matrix4, Point3, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::base::error::{Error, Role};
use crate::field::baked::BakedGrid;
use crate::field::mesh::MeshField;
use crate::field::Field;
use crate::geometry::cloud::{validate, LeftOut, Normalization};
use crate::geometry::tree::{build_tree, Tree};
use crate::pipeline::evaluate::{Evaluation, MovedSource};
use crate::pipeline::registration::Registration;
use crate::pipeline::settings::RegisterSettings;
use crate::pipeline::surface::{Surface, WithGrid};

/// The mesh's field with the points the polish and the quality figures use: samples on its
/// faces, unit frame.
#[derive(Clone, Debug)]
pub(crate) struct MeshSurface {
    field: MeshField,
    target: Vec<[f32; 3]>,
    tree: Tree,
    /// The samples' median spacing, computed when first asked for.
    spacing: std::sync::OnceLock<f64>,
}

impl Surface for MeshSurface {
    type Phi = MeshField;
    type Coarse = MeshField;
    fn phi(&self) -> &MeshField {
        &self.field
    }
    fn coarse(&self) -> &MeshField {
        &self.field
    }
    fn target(&self) -> &[[f32; 3]] {
        &self.target
    }
    fn tree(&self) -> &Tree {
        &self.tree
    }
    fn spacing(&self) -> f64 {
        *self
            .spacing
            .get_or_init(|| crate::geometry::tree::target_spacing(&self.target, &self.tree))
    }
    fn add_source_queries(&mut self, _: &[[f32; 3]]) {}
    fn refine(&mut self, _: usize, _: f32) {}
}

/// A target mesh as an exact distance field: register sources onto it with no fitting, as
/// onto a fitted [`crate::SdfModel`] with Φ frozen.
#[derive(Clone, Debug)]
pub struct MeshModel {
    norm: Normalization,
    surface: MeshSurface,
    /// The distance baked into a grid for the multi-start ([`crate::field::baked`]), made by
    /// the first registration (evaluating a transformation does not need it).
    grid: std::sync::OnceLock<std::sync::Arc<BakedGrid>>,
}

impl MeshModel {
    /// The model of the mesh `vertices` (user units) and `triangles` (indices into
    /// `vertices`). The polish and the quality figures use
    /// [`RegisterSettings::max_target_points`] points sampled uniformly by area on the faces
    /// (seeded by [`RegisterSettings::seed`]); the multi-start reads the distance baked into a
    /// grid ([`crate::field::baked`]), made by the first registration. Fails on a non-finite vertex, an index out of
    /// range, no triangles or no area.
    pub fn new(
        vertices: &[Point3<f64>],
        triangles: &[[usize; 3]],
        settings: &RegisterSettings,
    ) -> Result<Self, Error> {
        settings.validate()?;
        validate(vertices, Role::Target, 3)?;
        // Indices beyond u32 are out of range as well (MeshField::new says so).
        let indices: Vec<[u32; 3]> = triangles
            .iter()
            .map(|t| t.map(|i| u32::try_from(i).unwrap_or(u32::MAX)))
            .collect();
        let norm = Normalization::from_target(vertices)?;
        let unit_vertices: Vec<[f32; 3]> = vertices.iter().map(|p| norm.to_unit(p)).collect();
        let field = MeshField::new(&unit_vertices, &indices)?;
        let mut rng =
            ChaCha8Rng::seed_from_u64(settings.seed ^ crate::pipeline::target::FIT_SEED_SALT);
        let samples = crate::geometry::mesh::sample_surface(
            vertices,
            triangles,
            settings
                .max_target_points
                .max(crate::pipeline::settings::MIN_POINTS),
            &mut rng,
        )
        .ok_or_else(|| Error::InvalidMesh("the triangles have no area".into()))?;
        let target: Vec<[f32; 3]> = samples.iter().map(|p| norm.to_unit(p)).collect();
        let tree = build_tree(&target);
        Ok(MeshModel {
            norm,
            surface: MeshSurface {
                field,
                target,
                tree,
                spacing: std::sync::OnceLock::new(),
            },
            grid: std::sync::OnceLock::new(),
        })
    }

    /// Whether the distance is signed (a closed, consistently oriented mesh).
    pub fn is_signed(&self) -> bool {
        self.surface.field.is_signed()
    }

    /// Registers `source` (user units) onto the mesh: the multi-start (or `init`, mapping
    /// source into target), LM, the robust re-run when needed, the polish and the shift
    /// search, as [`crate::SdfModel::register`]; `settings.mlp`, `settings.fit` and
    /// `settings.max_target_points` are not read.
    pub fn register(
        &self,
        source: &[Point3<f64>],
        init: Option<&Isometry3<f64>>,
        settings: &RegisterSettings,
    ) -> Result<Registration, Error> {
        crate::pipeline::register::against(
            &self.norm,
            &WithGrid::lazy(&self.surface, &self.grid),
            source,
            init,
            settings,
            false,
            &|_| {},
        )
    }

    /// Φ and ∇Φ at `points` (target units and frame), in parallel.
    pub fn evaluate(&self, points: &[Point3<f64>]) -> (Vec<f64>, Vec<Vector3<f64>>) {
        crate::field::evaluate_user(&self.norm, &self.surface.field, points)
    }

    /// The distance at `points`, target units (negative inside when [`MeshModel::is_signed`]).
    pub fn distance(&self, points: &[Point3<f64>]) -> Vec<f64> {
        self.evaluate(points).0
    }

    /// The closest surface point of each of `points`, target units and frame.
    pub fn closest_points(&self, points: &[Point3<f64>]) -> Vec<Point3<f64>> {
        crate::field::closest_user(points, self.evaluate(points))
    }

    /// How well `source`, moved by `transformation` (source into the mesh's frame, `p_target =
    /// s R p_source + t`, rigid or a similarity), lies on the mesh: as
    /// [`crate::evaluate_registration`], with each point's exact distance to the faces in place
    /// of the distance to the nearest target point, at `max_distance` in the mesh's units.
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
            |moved| {
                let (phi, _) = self.surface.field.eval_points(moved, false);
                phi.iter().map(|d| d * d).collect()
            },
        )
    }

    /// The points sampled on the faces (target units and frame).
    pub fn target_points(&self) -> Vec<Point3<f64>> {
        self.surface
            .target
            .iter()
            .map(|p| {
                self.norm
                    .to_user(&Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64))
            })
            .collect()
    }
}
