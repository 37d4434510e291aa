//! The target as the registration stages see it ([`Surface`]): Φ, the target points and their
//! k-d tree; a fitted Φ is refined by the coarse-to-fine loop, a frozen one ([`WithGrid`]: a
//! stored model or a mesh) is not, and its multi-start reads Φ baked into a grid (a stored
//! model's on its first use).

use std::sync::{Arc, OnceLock};

use crate::field::baked::{Baked, BakedGrid};
use crate::field::sdf::SdfField;
use crate::field::Field;
use crate::fit::fitter::SdfFitter;
use crate::geometry::planes::{SharedPlanes, TargetPlanes};
use crate::geometry::tree::Tree;

/// The target as the registration stages use it: Φ, the (subsampled) target points in the unit
/// frame and their k-d tree; refinable when Φ is fitted.
pub(crate) trait Surface: Clone + Sync {
    /// The distance field.
    type Phi: Field;
    /// The field of the multi-start's first round: Φ itself, or Φ baked into a grid when Φ is
    /// frozen ([`crate::field::baked`]).
    type Coarse: Field;
    /// Φ.
    fn phi(&self) -> &Self::Phi;
    /// The multi-start's field.
    fn coarse(&self) -> &Self::Coarse;
    /// Target points, unit frame.
    fn target(&self) -> &[[f32; 3]];
    /// Their k-d tree.
    fn tree(&self) -> &Tree;
    /// Their median spacing (unit frame), computed once per target.
    fn spacing(&self) -> f64;
    /// Adds moved-source queries for a refinement of Φ (coarse-to-fine); an exact field has
    /// nothing to refine and ignores them.
    fn add_source_queries(&mut self, points: &[[f32; 3]]);
    /// Refines Φ for `steps` Adam steps at `lr`; an exact field ignores it.
    fn refine(&mut self, steps: usize, lr: f32);
    /// Whether Φ is a local model (a scene, [`crate::ModelKind::Local`]).
    fn is_local(&self) -> bool {
        false
    }
    /// The planes at the target's points of `k` points each, for a scene's polish: new ones,
    /// or a stored model's kept from earlier registrations.
    fn target_planes(&self, k: usize) -> std::sync::Arc<crate::geometry::planes::TargetPlanes> {
        std::sync::Arc::new(crate::geometry::planes::TargetPlanes::new(self.target(), k))
    }
}

impl Surface for SdfFitter {
    type Phi = SdfField;
    type Coarse = SdfField;
    fn phi(&self) -> &SdfField {
        self.field()
    }
    fn coarse(&self) -> &SdfField {
        self.field()
    }
    fn target(&self) -> &[[f32; 3]] {
        SdfFitter::target(self)
    }
    fn tree(&self) -> &Tree {
        SdfFitter::tree(self)
    }
    fn spacing(&self) -> f64 {
        SdfFitter::spacing(self)
    }
    fn add_source_queries(&mut self, points: &[[f32; 3]]) {
        SdfFitter::add_source_queries(self, points)
    }
    fn refine(&mut self, steps: usize, lr: f32) {
        self.train(steps, lr);
    }
    fn is_local(&self) -> bool {
        self.field().grid().is_some()
    }
}

/// Φ as the stages after the multi-start read it against a frozen target: Φ itself, or, for a
/// local model, Φ baked at the corners of its sparse grid ([`crate::field::local_grid::SparseBaked`]:
/// one lookup and eight loads instead of the MLP, the local part exactly, the MLP's part
/// interpolated over a voxel) and Φ itself beyond them.
pub(crate) enum FrozenPhi<'a, F: Field> {
    /// Φ itself.
    Exact(&'a F),
    /// Baked at a local model's corners.
    Sparse(Baked<'a, F, crate::field::local_grid::SparseBaked<'a>>),
}

impl<F: Field> Clone for FrozenPhi<'_, F> {
    fn clone(&self) -> Self {
        match self {
            Self::Exact(f) => Self::Exact(f),
            Self::Sparse(b) => Self::Sparse(*b),
        }
    }
}

impl<F: Field> Field for FrozenPhi<'_, F> {
    fn eval_block(
        &self,
        xs: &[[f32; 3]],
        values: &mut Vec<f32>,
        gradients: Option<&mut Vec<[f32; 3]>>,
    ) {
        match self {
            Self::Exact(f) => f.eval_block(xs, values, gradients),
            Self::Sparse(b) => b.eval_block(xs, values, gradients),
        }
    }
}

/// Where a frozen target's multi-start grid comes from.
#[derive(Clone, Copy)]
enum GridSource<'a> {
    /// Baked already.
    Ready(&'a BakedGrid),
    /// Baked from Φ on the first read of [`Surface::coarse`], into a cell that outlives the
    /// registration (a stored model's): a registration from a given pose through a scene's
    /// model, which runs no multi-start, never bakes it.
    Lazy(&'a OnceLock<Arc<BakedGrid>>),
}

/// A target whose Φ is fixed, as the registration stages see it: nothing is refined, and the
/// multi-start's first round reads Φ baked into a grid.
pub(crate) struct WithGrid<'a, S: Surface> {
    surface: &'a S,
    grid: GridSource<'a>,
    /// The multi-start's field, made on its first read.
    baked: OnceLock<Baked<'a, S::Phi>>,
    phi: FrozenPhi<'a, S::Phi>,
    /// The model's planes at the target's points, kept across registrations.
    planes: Option<&'a SharedPlanes>,
}

impl<'a, S: Surface> WithGrid<'a, S> {
    /// `surface` with its Φ's `grid`.
    pub(crate) fn new(surface: &'a S, grid: &'a BakedGrid) -> Self {
        Self::with_source(surface, GridSource::Ready(grid))
    }

    /// `surface` with its Φ baked into `cell` ([`crate::field::baked::baked_once`]) when the
    /// multi-start first reads it.
    pub(crate) fn lazy(surface: &'a S, cell: &'a OnceLock<Arc<BakedGrid>>) -> Self {
        Self::with_source(surface, GridSource::Lazy(cell))
    }

    fn with_source(surface: &'a S, grid: GridSource<'a>) -> Self {
        Self {
            surface,
            grid,
            baked: OnceLock::new(),
            phi: FrozenPhi::Exact(surface.phi()),
            planes: None,
        }
    }

    /// The same, the stages after the multi-start reading Φ baked at a local model's corners.
    pub(crate) fn with_sparse(mut self, sparse: crate::field::local_grid::SparseBaked<'a>) -> Self {
        self.phi = FrozenPhi::Sparse(Baked {
            grid: sparse,
            exact: self.surface.phi(),
        });
        self
    }

    /// The same, keeping a scene's polish planes in `planes` across registrations.
    pub(crate) fn with_planes(mut self, planes: &'a SharedPlanes) -> Self {
        self.planes = Some(planes);
        self
    }
}

impl<S: Surface> Clone for WithGrid<'_, S> {
    fn clone(&self) -> Self {
        Self {
            surface: self.surface,
            grid: self.grid,
            baked: self.baked.clone(),
            phi: self.phi.clone(),
            planes: self.planes,
        }
    }
}

impl<'a, S: Surface> Surface for WithGrid<'a, S> {
    type Phi = FrozenPhi<'a, S::Phi>;
    type Coarse = Baked<'a, S::Phi>;
    fn phi(&self) -> &FrozenPhi<'a, S::Phi> {
        &self.phi
    }
    fn coarse(&self) -> &Baked<'a, S::Phi> {
        // A lazy grid is baked by rayon tasks: see `get_or_make`.
        crate::base::pool::get_or_make(&self.baked, || {
            let exact: &'a S::Phi = self.surface.phi();
            let grid = match self.grid {
                GridSource::Ready(grid) => grid,
                GridSource::Lazy(cell) => crate::field::baked::baked_once(cell, exact),
            };
            Baked { grid, exact }
        })
    }
    fn target(&self) -> &[[f32; 3]] {
        self.surface.target()
    }
    fn tree(&self) -> &Tree {
        self.surface.tree()
    }
    fn spacing(&self) -> f64 {
        self.surface.spacing()
    }
    fn add_source_queries(&mut self, _: &[[f32; 3]]) {}
    fn refine(&mut self, _: usize, _: f32) {}
    fn is_local(&self) -> bool {
        self.surface.is_local()
    }
    fn target_planes(&self, k: usize) -> std::sync::Arc<TargetPlanes> {
        match self.planes {
            Some(shared) => shared.get(self.target(), k),
            None => self.surface.target_planes(k),
        }
    }
}
