//! Many views into one frame: [`align`] and its settings and result.
//!
//! The stages, each a function of its own:
//! 1. **models** — a stored model ([`SdfModel`]) of every scan, a few at a time
//!    ([`AlignSettings::models_at_once`]), each dropped once its pairs are registered; a scan
//!    that cannot be fitted (too few points, no extent) is left out;
//! 2. **pairs** — pairwise registrations through those models (Φ frozen, [`register_many`]):
//!    every pair when the scans are few ([`AlignSettings::all_pairs_up_to`]), else each scan with
//!    its next [`AlignSettings::neighbours`] in order, wrapping round (a loop); of each pair the
//!    scan with more points is the target, so the scans' order does not change the pairs (of
//!    two with as many, each scan is the target of about half its pairs, so that a bias of the
//!    one-sided objective does not grow along the order); from the given initial poses of
//!    both scans when there are any, else from nothing;
//! 3. **graph** — candidate edges (fitness ≥ [`AlignSettings::min_fitness`]; of a pair
//!    registered both ways, the way of higher fitness); a scan with several candidate edges that
//!    no cycle through a third scan confirms is kept only when two of its edges put it at the
//!    same pose, with the edges that agree (a scan of something else is left out); a spanning
//!    tree gives the starting poses (Kruskal by fitness, two groups of scans joined at the
//!    placement that the most fitness among the edges between them agrees on); an edge
//!    outside it is kept only when it agrees with the tree
//!    ([`AlignSettings::consistent_rotation_deg`],
//!    [`AlignSettings::consistent_translation`]); Gauss–Newton on the kept edges
//!    ([`crate::views::graph`]). A scan left unplaced is registered against one model of its
//!    placed partners, and the graph made again with that pose as one more measurement of where
//!    it lies (one of its edges that agrees places it); a scan still unplaced has its pairs
//!    registered the other way round (stage 2 again) and the graph is made again; a scan no
//!    kept edge then joins to the anchor is left out. Above [`AlignSettings::all_pairs_up_to`]
//!    scans, pairs of placed scans that overlap far apart along the kept edges are registered
//!    from the graph's poses ([`AlignSettings::closure_pairs`], loop closures) and the graph is
//!    made again. Each solve is repeated with the edges outside the tree that agree with the
//!    solved poses, though not with the tree's chain;
//! 4. **consensus** (off by default) — every pose refined at once, point-to-plane against the
//!    other scans' points where they overlap ([`crate::views::consensus`],
//!    [`AlignSettings::consensus`]);
//! 5. **joint refinement** — [`AlignSettings::joint_rounds`] times, each scan registered (Φ
//!    frozen, from its pose) against one model of all the other scans in the common frame, the
//!    anchor too; then every pose re-expressed in the anchor's frame.
//!
//! **Frames**: `poses[k]` maps scan `k`'s coordinates into the anchor scan's frame, user units.

use std::borrow::Cow;
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use nalgebra::{Isometry3, Point3};
use rayon::prelude::*;

use crate::base::check;
use crate::base::error::{Error, Role};
use crate::base::pool::in_pool;
use crate::batch::pairs::{register_many, Pair, PairTarget};
use crate::geometry::cloud::{bounding_box, usable, LeftOut, Normalization};
use crate::geometry::tree::{nearest_in_others, UnitBox, SEARCH_BOUND_MARGIN};
use crate::model::sdf_model::SdfModel;
use crate::pipeline::evaluate::Evaluation;
use crate::pipeline::registration::Registration;
use crate::pipeline::settings::{RegisterSettings, MIN_POINTS};
use crate::views::consensus::{consensus, ConsensusOutcome, ConsensusSettings};
use crate::views::free_space::{edge_in_free_space, DepthMap, SeenFrom};
use crate::views::graph::{optimise_robust, GraphEdge};

/// Rounds of Cauchy weights on the pose graph's edges ([`optimise_robust`]). Measured on the
/// procedural room's loop of 8 views: plain Gauss–Newton ends 0.32° / 35 mm off at worst (one
/// confident edge pulls), 4 rounds 0.031° / 1.5 mm.
const GRAPH_ROUNDS: usize = 4;

/// Times the pose graph is solved again with the edges outside the spanning tree that disagreed
/// with the tree's chain but agree with the solved poses ([`pose_graph`]): around a loop of many
/// views the tree's chain drifts past the agreement bounds where the solved poses do not.
const RECHECKS: usize = 2;

/// Settings of [`align`].
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct AlignSettings {
    /// Every pairwise registration's settings, and the models' fits. Default
    /// [`RegisterSettings::views`] (views overlap in part).
    pub register: RegisterSettings,
    /// The scan whose frame the poses map into. Default 0.
    pub anchor: usize,
    /// A pairwise registration is a candidate edge when its fitness (the share of the source
    /// within the inlier distance of the target) is at least this. Default 0.3.
    pub min_fitness: f64,
    /// Up to this many scans every pair is registered; above, each scan with its next
    /// [`Self::neighbours`] in order. Default 16.
    pub all_pairs_up_to: usize,
    /// See [`Self::all_pairs_up_to`]. Default 3.
    pub neighbours: usize,
    /// An edge outside the spanning tree is kept when its relative pose agrees with the tree's
    /// within this rotation, degrees… Default 2.
    pub consistent_rotation_deg: f64,
    /// …and this translation, a fraction of the median scan's largest bounding-box side.
    /// Default 0.02.
    pub consistent_translation: f64,
    /// Gauss–Newton iterations on the pose graph at most. Default 20.
    pub graph_iterations: usize,
    /// The multi-view point-to-plane refinement after the pose graph
    /// ([`crate::views::consensus`]); off by default.
    #[serde(default)]
    pub consensus: ConsensusSettings,
    /// Joint refinement rounds (each scan against one model of all the others); 0 skips.
    /// Default 0: measured on the procedural room's loop of 8 views, the robust pose graph
    /// alone ends at 0.031° / 1.5 mm at worst and one round at 0.046° / 4.1 mm; on the bunny's
    /// 10 scans the round changed each pose by a few hundredths of a degree either way, for
    /// 40 % more time; on a room with a sparser scan it slid one view 7.7 cm along a wall.
    pub joint_rounds: usize,
    /// Scans' models held at once: they are fitted this many at a time, in scan order, and each
    /// dropped once the pairs registered against it are done. Default 4 (a model of one of the
    /// procedural room's scans, 115,000 returns, takes about 24 MB).
    #[serde(default = "default_models_at_once")]
    pub models_at_once: usize,
    /// Worker threads for the pairs (one pair per worker) and the fits; 0 = one per core.
    pub threads: usize,
    /// Where each scan was seen from, in its own frame, for the free-space check
    /// ([`crate::views::free_space`]): a pair that puts more than
    /// [`Self::max_in_free_space`] of either scan where the other's sensor saw empty space is
    /// no edge. Default `None`: no check (sdfreg cannot tell a scan's sensor from its points).
    #[serde(default)]
    pub seen_from: Option<SeenFrom>,
    /// See [`Self::seen_from`]: a share of the scan's points whose cells in the other's depth
    /// map hold a return. Default 0.02 (right pairs of the Stanford bunny, the procedural room
    /// and real KITTI scans leave at most 0.32 % there; wrong ones 5.4–49 %).
    #[serde(default = "default_max_in_free_space")]
    pub max_in_free_space: f64,
    /// Above [`Self::all_pairs_up_to`] scans, once the graph has placed them, each scan joins at
    /// most this many more pairs, chosen by overlap in the common frame (loop closures): of the
    /// pairs not registered yet whose occupied cells overlap by at least
    /// [`Self::closure_min_overlap`], the one farthest apart along the kept edges first, at
    /// least [`Self::closure_min_hops`] apart. Registered from the graph's poses; the graph is
    /// then made again. 0 skips. Default 2: on the procedural room's loop of 100 views the
    /// views' mean error fell from 0.19° / 3.8 mm to 0.05° / 1.9 mm, for 1.34 times the time.
    #[serde(default = "default_closure_pairs")]
    pub closure_pairs: usize,
    /// See [`Self::closure_pairs`]: the cell the overlap is counted in, a fraction of the median
    /// scan's largest bounding-box side. Default 0.02.
    #[serde(default = "default_closure_cell")]
    pub closure_cell: f64,
    /// See [`Self::closure_pairs`]: two scans are a closure pair when at least this share of the
    /// smaller one's occupied cells are the other's too. Default 0.5.
    #[serde(default = "default_closure_min_overlap")]
    pub closure_min_overlap: f64,
    /// See [`Self::closure_pairs`]: …and at least this many kept edges apart. Default 5 (a
    /// loop of 25 views, each paired with its next 3, is at most 4 across: it gets none).
    #[serde(default = "default_closure_min_hops")]
    pub closure_min_hops: usize,
}

fn default_closure_pairs() -> usize {
    2
}

fn default_closure_cell() -> f64 {
    0.02
}

fn default_closure_min_overlap() -> f64 {
    0.5
}

fn default_closure_min_hops() -> usize {
    5
}

fn default_models_at_once() -> usize {
    4
}

fn default_max_in_free_space() -> f64 {
    0.02
}

impl Default for AlignSettings {
    fn default() -> Self {
        Self {
            register: RegisterSettings::views(),
            anchor: 0,
            min_fitness: 0.3,
            all_pairs_up_to: 16,
            neighbours: 3,
            consistent_rotation_deg: 2.0,
            consistent_translation: 0.02,
            graph_iterations: 20,
            consensus: ConsensusSettings::default(),
            joint_rounds: 0,
            models_at_once: default_models_at_once(),
            threads: 0,
            seen_from: None,
            max_in_free_space: default_max_in_free_space(),
            closure_pairs: default_closure_pairs(),
            closure_cell: default_closure_cell(),
            closure_min_overlap: default_closure_min_overlap(),
            closure_min_hops: default_closure_min_hops(),
        }
    }
}

impl AlignSettings {
    /// The settings of every registration and model fit: [`Self::register`] with
    /// [`Self::threads`].
    fn registration(&self) -> RegisterSettings {
        RegisterSettings {
            threads: self.threads,
            ..self.register.clone()
        }
    }

    /// Checks every field; the error names it (`align.min_fitness`, …).
    pub fn validate(&self) -> Result<(), Error> {
        self.register.validate()?;
        check::fraction_below_one("align.min_fitness", self.min_fitness)?;
        check::count_at_least("align.neighbours", self.neighbours, 1)?;
        check::count_at_least("align.models_at_once", self.models_at_once, 1)?;
        check::non_negative(
            "align.consistent_rotation_deg",
            self.consistent_rotation_deg,
        )?;
        check::non_negative("align.consistent_translation", self.consistent_translation)?;
        if let Some(seen) = &self.seen_from {
            seen.validate("align.seen_from")?;
        }
        check::in_unit_interval("align.max_in_free_space", self.max_in_free_space)?;
        check::positive("align.closure_cell", self.closure_cell)?;
        check::in_unit_interval("align.closure_min_overlap", self.closure_min_overlap)?;
        check::count_at_least("align.closure_min_hops", self.closure_min_hops, 2)?;
        self.consensus.validate()
    }
}

/// One pairwise registration: `source` registered onto `target`'s model.
#[derive(Clone, Debug)]
pub struct Edge {
    /// The scan registered against.
    pub target: usize,
    /// The scan moved.
    pub source: usize,
    /// The registration (its pose maps the source scan into the target scan's frame), or why
    /// it failed.
    pub registration: Result<Registration, String>,
    /// Whether the pose graph used it.
    pub kept: bool,
    /// With [`AlignSettings::seen_from`]: the larger of the two shares of a scan's points
    /// that this registration puts in the other scan's free space (above
    /// [`AlignSettings::max_in_free_space`] it is no edge); `None` unchecked.
    pub in_free_space: Option<f64>,
}

impl Edge {
    /// The registration's fitness, 0 when it failed.
    pub fn fitness(&self) -> f64 {
        self.registration.as_ref().map_or(0.0, |r| r.fitness)
    }
}

/// Wall time of each stage of [`align`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AlignTimes {
    /// Fitting each scan's model.
    pub models: Duration,
    /// The pairwise registrations.
    pub pairs: Duration,
    /// The spanning tree, the edge check and the pose graph.
    pub graph: Duration,
    /// Registering the scans the pose graph left unplaced against one model of their placed
    /// partners.
    pub unplaced: Duration,
    /// The multi-view refinement.
    pub consensus: Duration,
    /// The joint refinement.
    pub joint: Duration,
}

/// What [`align`] found.
#[derive(Clone, Debug)]
pub struct Alignment {
    /// The scan whose frame the poses map into.
    pub anchor: usize,
    /// Per scan, the pose mapping its coordinates into the anchor's frame; `None` for a scan
    /// left out (see [`Self::left_out`]).
    pub poses: Vec<Option<Isometry3<f64>>>,
    /// Per scan left out, its index and why.
    pub left_out: Vec<(usize, String)>,
    /// Every pairwise registration tried.
    pub edges: Vec<Edge>,
    /// Per scan, the best fitness of a kept edge it is part of (0 when none).
    pub fitness: Vec<f64>,
    /// What the multi-view refinement did (all zero when it did not run).
    pub consensus: ConsensusOutcome,
    /// Each stage's wall time.
    pub times: AlignTimes,
    /// The whole call's wall time.
    pub time: Duration,
}

impl Alignment {
    /// Every placed scan's points in the anchor's frame, one cloud.
    pub fn merged(&self, scans: &[Vec<Point3<f64>>]) -> Vec<Point3<f64>> {
        merged_except(scans, &self.poses, None)
    }

    /// One model of every placed scan in the anchor's frame ([`SdfModel::fit`] of
    /// [`Self::merged`]).
    pub fn merged_model(
        &self,
        scans: &[Vec<Point3<f64>>],
        settings: &RegisterSettings,
    ) -> Result<SdfModel, Error> {
        SdfModel::fit(&self.merged(scans), settings)
    }

    /// How well each placed scan lies on the others once aligned, with no reference: per scan,
    /// [`crate::evaluate_registration`] of the scan, moved by its pose, against every other
    /// placed scan in the anchor's frame, at `max_distance` (the scans' units). `None` for a
    /// scan left out. `scans` are the scans given to [`align`], in that order.
    ///
    /// Each scan's missing returns and stray points are left out of it, as a registration
    /// leaves them out; the target's left-out counts are those of the other scans whose
    /// bounding boxes come within `max_distance` of the scan's (no other scan can hold a point
    /// that near). The distances are measured in one unit frame for all the scans (f32, as
    /// [`crate::evaluate_registration`] measures them in the target's), so a figure may differ
    /// from that call's in the last digits. Exact nearest points, at about `log₂ n` k-d tree
    /// look-ups per point for `n` scans.
    ///
    /// # Errors
    /// `scans` not as many as the poses; `max_distance` not positive and finite.
    pub fn evaluate(
        &self,
        scans: &[Vec<Point3<f64>>],
        max_distance: f64,
    ) -> Result<Vec<Option<Evaluation>>, Error> {
        if scans.len() != self.poses.len() {
            return Err(Error::InvalidSetting {
                name: "scans",
                reason: format!(
                    "{} scans for an alignment of {}",
                    scans.len(),
                    self.poses.len()
                ),
            });
        }
        check::positive("max_distance", max_distance)?;
        // Each placed scan without its missing returns and stray points (as a registration
        // leaves them out), moved into the anchor's frame, with its bounding box there.
        let mut placed: Vec<(usize, Placed)> = Vec::new();
        let mut moved: Vec<Vec<Point3<f64>>> = Vec::new();
        for (k, (scan, pose)) in scans.iter().zip(&self.poses).enumerate() {
            let Some(pose) = pose else { continue };
            let (points, left_out) = usable(scan, Role::Source, MIN_POINTS)?;
            let points: Vec<Point3<f64>> = points.iter().map(|p| pose * p).collect();
            let (lo, hi) = bounding_box(&points).expect("usable leaves points");
            placed.push((k, Placed { left_out, lo, hi }));
            moved.push(points);
        }
        let mut evaluations = vec![None; scans.len()];
        let Some((lo, hi)) = placed
            .iter()
            .map(|(_, p)| (p.lo, p.hi))
            .reduce(|a, b| (a.0.inf(&b.0), a.1.sup(&b.1)))
        else {
            return Ok(evaluations);
        };
        // One unit frame for all (that of the box of them all), each scan's points and box in it;
        // each scan's anchor-frame copy is dropped once converted.
        let norm = Normalization::from_target(&[lo, hi])?;
        let unit: Vec<Vec<[f32; 3]>> = moved
            .into_iter()
            .map(|points| points.par_iter().map(|x| norm.to_unit(x)).collect())
            .collect();
        let boxes: Vec<UnitBox> = placed
            .iter()
            .map(|(_, p)| (norm.to_unit(&p.lo), norm.to_unit(&p.hi)))
            .collect();
        // A little beyond the distance, so that f32 rounding leaves no inlier unsearched.
        let reach = (max_distance / norm.scale * (1.0 + SEARCH_BOUND_MARGIN)) as f32;
        let d2 = in_pool(0, || nearest_in_others(&unit, &boxes, reach))?;
        let near = |a: &Placed, b: &Placed| {
            (0..3).all(|i| a.lo[i] - max_distance <= b.hi[i] && b.lo[i] <= a.hi[i] + max_distance)
        };
        for ((k, own), d2) in placed.iter().zip(&d2) {
            let target_left_out = placed
                .iter()
                .filter(|(j, other)| j != k && near(own, other))
                .fold(LeftOut::default(), |sum, (_, p)| LeftOut {
                    missing_returns: sum.missing_returns + p.left_out.missing_returns,
                    stray: sum.stray + p.left_out.stray,
                });
            evaluations[*k] = Some(Evaluation::from_distances2(
                d2,
                norm.scale,
                max_distance,
                own.left_out,
                target_left_out,
            ));
        }
        Ok(evaluations)
    }
}

/// A placed scan as [`Alignment::evaluate`] counts it (its points are measured apart).
struct Placed {
    /// The points left out.
    left_out: LeftOut,
    /// Its bounding box there.
    lo: Point3<f64>,
    hi: Point3<f64>,
}

/// The placed scans' points in the common frame, but scan `except`.
fn merged_except(
    scans: &[Vec<Point3<f64>>],
    poses: &[Option<Isometry3<f64>>],
    except: Option<usize>,
) -> Vec<Point3<f64>> {
    scans
        .iter()
        .zip(poses)
        .enumerate()
        .filter(|(k, _)| Some(*k) != except)
        .filter_map(|(_, (scan, pose))| pose.map(|t| scan.iter().map(move |p| t * p)))
        .flatten()
        .collect()
}

/// Aligns `scans` (each in its own frame, user units) into the frame of
/// [`AlignSettings::anchor`]; `init`, when given, holds each scan's approximate pose in that
/// frame (a turntable's angles, odometry; `None` for a scan without one: its pairs are
/// registered from nothing). See the module docs.
pub fn align(
    scans: &[Vec<Point3<f64>>],
    init: Option<&[Option<Isometry3<f64>>]>,
    s: &AlignSettings,
) -> Result<Alignment, Error> {
    let start = Instant::now();
    check_input(scans, init, s)?;
    let mut times = AlignTimes::default();
    let pairs = pair_list(scans, s);
    let mut left_out = Vec::new();
    // Each scan's depth map for the free-space check, made when a pair first needs it.
    let maps: Vec<OnceLock<Option<DepthMap>>> = match s.seen_from {
        Some(_) => scans.iter().map(|_| OnceLock::new()).collect(),
        None => Vec::new(),
    };
    let mut edges = models_and_pairs(
        scans,
        &pairs,
        &mut left_out,
        true,
        init,
        s,
        &maps,
        &mut times,
    )?;
    let usable = scans.len() - left_out.len();
    if usable < 2 {
        return Err(Error::TooFewScans { found: usable });
    }
    let mut clock = Instant::now();
    let none = vec![None; scans.len()];
    let mut poses = pose_graph(scans, &mut edges, init, &none, s);
    lap(&mut clock, &mut times.graph);
    let placed = unplaced_against_partners(scans, &edges, &poses, &mut left_out, init, s);
    lap(&mut clock, &mut times.unplaced);
    if placed.iter().any(Option::is_some) {
        edges.iter_mut().for_each(|e| e.kept = false);
        poses = pose_graph(scans, &mut edges, init, &placed, s);
        lap(&mut clock, &mut times.graph);
    }
    // Stage 2 again for `pairs` (from the poses `from`), and the graph made again.
    let more_pairs = |pairs: &[(usize, usize)],
                      from: Option<&[Option<Isometry3<f64>>]>,
                      edges: &mut Vec<Edge>,
                      left_out: &mut Vec<(usize, String)>,
                      times: &mut AlignTimes| {
        edges.extend(models_and_pairs(
            scans, pairs, left_out, false, from, s, &maps, times,
        )?);
        edges.iter_mut().for_each(|e| e.kept = false);
        let clock = Instant::now();
        let poses = pose_graph(scans, edges, init, &placed, s);
        times.graph += clock.elapsed();
        Ok::<_, Error>(poses)
    };
    if let Some(reversed) = unplaced_reversed(&edges, &poses, &left_out) {
        poses = more_pairs(&reversed, init, &mut edges, &mut left_out, &mut times)?;
    }
    clock = Instant::now();
    let closures = closure_pair_list(scans, &edges, &poses, s)?;
    lap(&mut clock, &mut times.graph);
    if !closures.is_empty() {
        poses = more_pairs(
            &closures,
            Some(&poses),
            &mut edges,
            &mut left_out,
            &mut times,
        )?;
    }
    clock = Instant::now();
    let consensus = consensus(scans, &mut poses, s.anchor, &s.consensus);
    lap(&mut clock, &mut times.consensus);
    for _ in 0..s.joint_rounds {
        joint_round(scans, &mut poses, s)?;
    }
    lap(&mut clock, &mut times.joint);
    for (k, pose) in poses.iter().enumerate() {
        if pose.is_none() && !is_left_out(&left_out, k) {
            left_out.push((k, "no pairwise registration joins it to the others".into()));
        }
    }
    left_out.sort_by_key(|(k, _)| *k);
    let fitness = (0..scans.len())
        .map(|k| {
            edges
                .iter()
                .filter(|e| e.kept && (e.source == k || e.target == k))
                .map(Edge::fitness)
                .fold(0.0, f64::max)
        })
        .collect();
    Ok(Alignment {
        anchor: s.anchor,
        poses,
        left_out,
        edges,
        fitness,
        consensus,
        times,
        time: start.elapsed(),
    })
}

/// Whether scan `k` is among those `left_out`.
fn is_left_out(left_out: &[(usize, String)], k: usize) -> bool {
    left_out.iter().any(|(i, _)| *i == k)
}

/// Scan `j`'s pose in scan `i`'s frame by the poses `p` (each scan into one frame), when both
/// have one.
fn relative(p: Option<&[Option<Isometry3<f64>>]>, i: usize, j: usize) -> Option<Isometry3<f64>> {
    let p = p?;
    Some(p[i]?.inverse() * p[j]?)
}

/// Adds the time since `clock` to `time` and restarts `clock`.
fn lap(clock: &mut Instant, time: &mut Duration) {
    *time += clock.elapsed();
    *clock = Instant::now();
}

/// At least two scans, valid settings, an anchor among the scans, one initial pose (or `None`)
/// per scan.
fn check_input(
    scans: &[Vec<Point3<f64>>],
    init: Option<&[Option<Isometry3<f64>>]>,
    s: &AlignSettings,
) -> Result<(), Error> {
    if scans.len() < 2 {
        return Err(Error::TooFewScans { found: scans.len() });
    }
    s.validate()?;
    if s.anchor >= scans.len() {
        return Err(Error::InvalidSetting {
            name: "align.anchor",
            reason: format!(
                "must name one of the {} scans, got {}",
                scans.len(),
                s.anchor
            ),
        });
    }
    if init.is_some_and(|p| p.len() != scans.len()) {
        return Err(Error::InvalidSetting {
            name: "align.init",
            reason: format!("needs one pose per scan ({})", scans.len()),
        });
    }
    Ok(())
}

/// The pairs `(target, source)` to register: all when the scans are few, else each with its
/// next neighbours, wrapping round. Of each pair the scan with more points is the target (its
/// model is Φ), the other the source, so the scans' order changes neither the pairs'
/// directions nor their results when all pairs are registered; of two with as many (a
/// simulator's or an organised scanner's fixed count), [`later_is_target`] makes each scan the
/// target of about half its pairs. (The earlier scan as the target made the anchor the target
/// of every pair and the last scan of none; each pose then took a bias of the one-sided
/// objective once per pair it was the source of: on the procedural room's loop of 8 views the
/// mean error over 12 noise draws rose from 0.0149° at view 2 to 0.0228° at view 4 and 0.0222°
/// at view 7, 0.0187° over views 1–7, against 0.0135–0.0200° and 0.0172° now. A hash of the
/// points as the tie-break made the procedural room loop's scan 0 the source onto the models
/// of scans 3, 4 and 5, where the scene's shift search takes a candidate 0.1 m up — rings on
/// the walls laid onto rings — and the loop ended 77 mm off.)
fn pair_list(scans: &[Vec<Point3<f64>>], s: &AlignSettings) -> Vec<(usize, usize)> {
    let n = scans.len();
    let mut pairs: Vec<(usize, usize)> = if n <= s.all_pairs_up_to {
        (0..n)
            .flat_map(|i| (i + 1..n).map(move |j| (i, j)))
            .collect()
    } else {
        let mut pairs: Vec<(usize, usize)> = (0..n)
            .flat_map(|i| (1..=s.neighbours.min(n - 1)).map(move |d| (i, (i + d) % n)))
            .map(|(i, j)| (i.min(j), i.max(j)))
            .collect();
        pairs.sort_unstable();
        pairs.dedup();
        pairs
    };
    for (i, j) in &mut pairs {
        if later_is_target(*i, *j, scans[*i].len(), scans[*j].len()) {
            std::mem::swap(i, j);
        }
    }
    pairs
}

/// Of the pair of scans `i < j` (with `ni` and `nj` points), whether `j` is the target: the
/// scan with more points is; of two with as many, `i` when `i + j` is odd, else `j`, so each
/// scan is the target of about half its pairs.
fn later_is_target(i: usize, j: usize, ni: usize, nj: usize) -> bool {
    match nj.cmp(&ni) {
        std::cmp::Ordering::Greater => true,
        std::cmp::Ordering::Less => false,
        std::cmp::Ordering::Equal => (i + j) % 2 == 0,
    }
}

/// Stages 1 and 2: each scan's model and the pairwise registrations through them. The models
/// are fitted [`AlignSettings::models_at_once`] at a time, in scan order, and each is dropped
/// once the pairs registered against it are done, so memory holds a few models, not one per
/// scan. With `fit_all` the scans no pair registers against are fitted too (and dropped): one
/// that cannot be fitted cannot be a source either, and is left out. A scan found unfittable is
/// added to `left_out` and every pair with it dropped. With [`AlignSettings::seen_from`] each
/// registration's free-space share is measured against the scans' depth `maps` (one slot a
/// scan, filled when first needed). Adds each stage's time to `times`.
#[allow(clippy::too_many_arguments)]
fn models_and_pairs(
    scans: &[Vec<Point3<f64>>],
    pairs: &[(usize, usize)],
    left_out: &mut Vec<(usize, String)>,
    fit_all: bool,
    init: Option<&[Option<Isometry3<f64>>]>,
    s: &AlignSettings,
    maps: &[OnceLock<Option<DepthMap>>],
    times: &mut AlignTimes,
) -> Result<Vec<Edge>, Error> {
    let settings = s.registration();
    let targets: Vec<usize> = (0..scans.len())
        .filter(|&k| fit_all || pairs.iter().any(|&(i, _)| i == k))
        .filter(|&k| !is_left_out(left_out, k))
        .collect();
    let mut edges = Vec::new();
    for chunk in targets.chunks(s.models_at_once.max(1)) {
        let clock = Instant::now();
        let models: Vec<(usize, SdfModel)> = chunk
            .iter()
            .filter_map(|&k| match SdfModel::fit(&scans[k], &settings) {
                Ok(model) => Some((k, model)),
                Err(e) => {
                    left_out.push((k, e.to_string()));
                    None
                }
            })
            .collect();
        times.models += clock.elapsed();
        let clock = Instant::now();
        let tried: Vec<(usize, usize, &SdfModel)> = pairs
            .iter()
            .filter(|&&(_, j)| !is_left_out(left_out, j))
            .filter_map(|&(i, j)| {
                let (_, model) = models.iter().find(|(k, _)| *k == i)?;
                Some((i, j, model))
            })
            .collect();
        let batch: Vec<Pair<'_>> = tried
            .iter()
            .map(|&(i, j, model)| Pair {
                source: Cow::Borrowed(&scans[j]),
                target: PairTarget::Model(model),
                init: relative(init, i, j),
                seed: None,
            })
            .collect();
        let results = register_many(&batch, &s.register, s.threads)?;
        // Each edge's free-space check (and the depth maps it first needs) on the pairs' pool.
        let checked: Vec<Edge> = in_pool(s.threads, || {
            tried
                .into_par_iter()
                .zip(results)
                .map(|((target, source, _), r)| {
                    let registration = r.map_err(|e| e.to_string());
                    let in_free_space = registration.as_ref().ok().and_then(|r| {
                        let map = |k: usize| {
                            maps.get(k)?
                                .get_or_init(|| {
                                    s.seen_from
                                        .as_ref()
                                        .and_then(|v| DepthMap::new(&scans[k], v))
                                })
                                .as_ref()
                        };
                        edge_in_free_space(
                            (&scans[target], map(target)?),
                            (&scans[source], map(source)?),
                            &r.t_target_source,
                        )
                    });
                    Edge {
                        target,
                        source,
                        registration,
                        kept: false,
                        in_free_space,
                    }
                })
                .collect()
        })?;
        edges.extend(checked);
        times.pairs += clock.elapsed();
    }
    edges.retain(|e| !is_left_out(left_out, e.source) && !is_left_out(left_out, e.target));
    Ok(edges)
}

/// Stage 2 again, for the scans the pose graph left unplaced (a scan of something else, or a
/// real scan whose model the others failed to register onto: the bunny's `chin`, early in a
/// shuffled order, was the target of 8 of its pairs and 7 of them were wrong): their pairs the
/// other way round, `None` when every scan not left out was placed.
fn unplaced_reversed(
    edges: &[Edge],
    poses: &[Option<Isometry3<f64>>],
    left_out: &[(usize, String)],
) -> Option<Vec<(usize, usize)>> {
    let unplaced = |k: usize| poses[k].is_none() && !is_left_out(left_out, k);
    let reversed: Vec<(usize, usize)> = edges
        .iter()
        .filter(|e| unplaced(e.target) || unplaced(e.source))
        .map(|e| (e.source, e.target))
        .collect();
    (!reversed.is_empty()).then_some(reversed)
}

/// Stage 3 again for a sparse graph ([`AlignSettings::closure_pairs`]): once the graph has
/// placed the scans, more pairs chosen by overlap, as loop closures. Of the placed scans' pairs
/// not registered yet whose occupied cells in the common frame (cells of
/// [`AlignSettings::closure_cell`] of the median scan's size) overlap by at least
/// [`AlignSettings::closure_min_overlap`] of the smaller scan's, the pair farthest apart along
/// the kept edges is taken first (then the larger overlap), at least
/// [`AlignSettings::closure_min_hops`] edges apart, each scan in at most
/// [`AlignSettings::closure_pairs`] of them; each taken pair shortens the others' paths. A
/// scan's pose is a chain of edges from the anchor, and its error grows with the chain as a
/// random walk: on the procedural room's loop of 100 views, each with its next 3, the views
/// end 0.19° / 3.8 mm off on average, 0.34° / 13 mm at worst; with two closure pairs a scan at
/// least 5 edges apart, 0.05° / 1.9 mm and 0.14° / 4.0 mm. Nearer pairs (3 edges) did as well
/// there but made a loop of 25 views worse (0.037–0.055° on average over four noise draws
/// instead of 0.027–0.037°): the pairs across the room fit a little worse than the neighbours,
/// which a short loop's graph needs no help from. The pairs come `(target, source)`, the scan
/// with more points the target, as [`pair_list`]'s.
fn closure_pair_list(
    scans: &[Vec<Point3<f64>>],
    edges: &[Edge],
    poses: &[Option<Isometry3<f64>>],
    s: &AlignSettings,
) -> Result<Vec<(usize, usize)>, Error> {
    let n = scans.len();
    if s.closure_pairs == 0 || n <= s.all_pairs_up_to {
        return Ok(Vec::new());
    }
    let candidates = in_pool(s.threads, || closure_candidates(scans, edges, poses, s))?;
    // Hops along the kept edges between every two scans.
    let kept: Vec<(usize, usize)> = edges
        .iter()
        .filter(|e| e.kept)
        .map(|e| (e.target, e.source))
        .collect();
    let mut hops: Vec<Vec<usize>> = (0..n).map(|k| hops_from(k, &kept, n)).collect();
    let mut quota = vec![s.closure_pairs; n];
    let mut chosen = Vec::new();
    loop {
        let best = candidates
            .iter()
            .filter(|&&(i, j, _)| quota[i] > 0 && quota[j] > 0)
            .filter(|&&(i, j, _)| hops[i][j] >= s.closure_min_hops)
            .max_by(|x, y| {
                (hops[x.0][x.1], x.2)
                    .partial_cmp(&(hops[y.0][y.1], y.2))
                    .unwrap_or(std::cmp::Ordering::Equal)
                    .then((y.0, y.1).cmp(&(x.0, x.1)))
            })
            .copied();
        let Some((a, b, _)) = best else {
            break;
        };
        quota[a] -= 1;
        quota[b] -= 1;
        chosen.push((a, b));
        // The new edge shortens every path that runs better through it.
        for u in 0..n {
            for v in 0..n {
                let through = (hops[u][a] + 1 + hops[b][v]).min(hops[u][b] + 1 + hops[a][v]);
                if through < hops[u][v] {
                    hops[u][v] = through;
                }
            }
        }
    }
    for (i, j) in &mut chosen {
        if later_is_target(*i, *j, scans[*i].len(), scans[*j].len()) {
            std::mem::swap(i, j);
        }
    }
    Ok(chosen)
}

/// [`closure_pair_list`]'s candidates `(i, j, overlap)`, `i < j`: pairs of placed scans not
/// registered yet whose occupied cells overlap by at least
/// [`AlignSettings::closure_min_overlap`] of the smaller scan's (run within the pool).
fn closure_candidates(
    scans: &[Vec<Point3<f64>>],
    edges: &[Edge],
    poses: &[Option<Isometry3<f64>>],
    s: &AlignSettings,
) -> Vec<(usize, usize, f64)> {
    let n = scans.len();
    let cell = s.closure_cell * median_extent(scans);
    // Each placed scan's occupied cells in the common frame, from at most 8192 of its points.
    let cells: Vec<Option<std::collections::HashSet<[i64; 3]>>> = scans
        .par_iter()
        .zip(poses)
        .map(|(scan, pose)| {
            let pose = pose.as_ref()?;
            let stride = scan.len().div_ceil(8192).max(1);
            Some(
                scan.iter()
                    .step_by(stride)
                    .map(|p| {
                        let q = pose * p;
                        [q.x, q.y, q.z].map(|v| (v / cell).floor() as i64)
                    })
                    .collect(),
            )
        })
        .collect();
    let registered: std::collections::HashSet<(usize, usize)> = edges
        .iter()
        .flat_map(|e| [(e.target, e.source), (e.source, e.target)])
        .collect();
    // Each scan's cells' bounding box: two scans whose boxes are apart share no cell.
    let boxes: Vec<Option<([i64; 3], [i64; 3])>> = cells
        .iter()
        .map(|c| {
            let c = c.as_ref()?;
            let first = *c.iter().next()?;
            Some(c.iter().fold((first, first), |(lo, hi), x| {
                (
                    std::array::from_fn(|k| lo[k].min(x[k])),
                    std::array::from_fn(|k| hi[k].max(x[k])),
                )
            }))
        })
        .collect();
    let apart = |i: usize, j: usize| match (boxes[i], boxes[j]) {
        (Some((lo_i, hi_i)), Some((lo_j, hi_j))) => {
            (0..3).any(|k| hi_i[k] < lo_j[k] || hi_j[k] < lo_i[k])
        }
        _ => true,
    };
    let overlap = |i: usize, j: usize| -> Option<f64> {
        if registered.contains(&(i, j)) || apart(i, j) {
            return None;
        }
        let (a, b) = (cells[i].as_ref()?, cells[j].as_ref()?);
        let (small, large) = if a.len() <= b.len() { (a, b) } else { (b, a) };
        let shared = small.iter().filter(|c| large.contains(*c)).count();
        Some(shared as f64 / small.len() as f64)
    };
    (0..n)
        .into_par_iter()
        .flat_map_iter(|i| (i + 1..n).map(move |j| (i, j)))
        .filter_map(|(i, j)| Some((i, j, overlap(i, j)?)))
        .filter(|&(_, _, o)| o >= s.closure_min_overlap)
        .collect()
}

/// The number of `edges` (pairs of scan indices) on the shortest path from scan `start` to each
/// of the `n` scans; `n + 1` for a scan no path reaches.
fn hops_from(start: usize, edges: &[(usize, usize)], n: usize) -> Vec<usize> {
    let mut hops = vec![n + 1; n];
    hops[start] = 0;
    let mut queue = std::collections::VecDeque::from([start]);
    while let Some(k) = queue.pop_front() {
        for &(a, b) in edges {
            let other = match (a == k, b == k) {
                (true, _) => b,
                (_, true) => a,
                _ => continue,
            };
            if hops[other] > hops[k] + 1 {
                hops[other] = hops[k] + 1;
                queue.push_back(other);
            }
        }
    }
    hops
}

/// Stage 3 again, for the scans the pose graph left unplaced (not left out) that were paired
/// with two or more placed scans: each registered (from nothing, or from its initial pose)
/// against one model of those placed partners in the anchor's frame. Returns per scan where
/// that put it (`None` for the others). It places no scan by itself: [`pose_graph`] counts it
/// as one more measurement of where the scan lies, so one of the scan's own edges that agrees
/// with it places the scan; a scan of something else is put somewhere else by each. On the
/// bunny's 10 scans, `bun270`'s only right edge of the first round was the one with `bun315`
/// (its other 12 were 68–170° off): one model of its 9 partners and one registration confirm
/// it, where registering its 9 pairs the other way round ([`unplaced_reversed`]) took 6 more
/// models and 9 more pairs. A scan whose fitness against all its placed partners at once is
/// below [`AlignSettings::min_fitness`] lies on none of them: it is added to `left_out` (a
/// ModelNet chair among the bunny's scans: 0.16; the bunny's scans 0.69–0.95), and its pairs
/// are not registered the other way round.
fn unplaced_against_partners(
    scans: &[Vec<Point3<f64>>],
    edges: &[Edge],
    poses: &[Option<Isometry3<f64>>],
    left_out: &mut Vec<(usize, String)>,
    init: Option<&[Option<Isometry3<f64>>]>,
    s: &AlignSettings,
) -> Vec<Option<Isometry3<f64>>> {
    let settings = s.registration();
    let mut placed = vec![None; scans.len()];
    let unplaced: Vec<usize> = (0..scans.len())
        .filter(|&k| poses[k].is_none() && !is_left_out(left_out, k))
        .collect();
    for k in unplaced {
        let paired = |j: usize| {
            edges
                .iter()
                .any(|e| (e.target, e.source) == (k, j) || (e.target, e.source) == (j, k))
        };
        let partners: Vec<Option<Isometry3<f64>>> = (0..scans.len())
            .map(|j| poses[j].filter(|_| paired(j)))
            .collect();
        let count = partners.iter().flatten().count();
        if count < 2 {
            continue;
        }
        // A fit or a registration that fails measures nothing: the scan's pairs then go round
        // the other way, as before this stage (the scans themselves were checked by stage 1).
        let start = relative(init, s.anchor, k);
        let Ok(r) = against_the_others(scans, &partners, k, start.as_ref(), &settings) else {
            continue;
        };
        if r.fitness >= s.min_fitness {
            placed[k] = Some(r.t_target_source);
        } else {
            left_out.push((
                k,
                format!(
                    "lies on none of the other scans: registered against one model of the {count} \
                     placed scans it was paired with, {:.0} % of it lies on them (at least {:.0} % \
                     needed)",
                    100.0 * r.fitness,
                    100.0 * s.min_fitness
                ),
            ));
        }
    }
    placed
}

/// Stage 3: the spanning tree, the edge check and the pose graph; marks the kept edges and
/// returns each scan's pose (`None`: not joined to the anchor). `placed[k]`, when given, is one
/// more measurement of scan `k`'s pose (by [`unplaced_against_partners`]) for the check of an
/// unconfirmed scan's edges.
fn pose_graph(
    scans: &[Vec<Point3<f64>>],
    edges: &mut [Edge],
    init: Option<&[Option<Isometry3<f64>>]>,
    placed: &[Option<Isometry3<f64>>],
    s: &AlignSettings,
) -> Vec<Option<Isometry3<f64>>> {
    let n = scans.len();
    // Of a pair registered both ways, the way with the higher fitness.
    let twin_wins = |e: usize| {
        let (a, b) = (edges[e].target, edges[e].source);
        edges.iter().enumerate().any(|(f, o)| {
            f != e
                && (o.target, o.source) == (b, a)
                && (o.fitness(), std::cmp::Reverse(f)) > (edges[e].fitness(), std::cmp::Reverse(e))
        })
    };
    let candidates: Vec<usize> = (0..edges.len())
        .filter(|&e| edges[e].registration.is_ok() && edges[e].fitness() >= s.min_fitness)
        .filter(|&e| {
            edges[e]
                .in_free_space
                .is_none_or(|v| v <= s.max_in_free_space)
        })
        .filter(|&e| !twin_wins(e))
        .collect();
    let extent = median_extent(scans);
    let agree = |d: &Isometry3<f64>| {
        d.rotation.angle().to_degrees() <= s.consistent_rotation_deg
            && d.translation.vector.norm() <= s.consistent_translation * extent
    };
    // A first tree over the scans that cycles confirm (and those with fewer than two edges);
    // then each unconfirmed scan is kept only when two of its edges agree on where those put it
    // (a scan of something else is put somewhere else by every registration).
    let unconfirmed = unconfirmed_scans(edges, &candidates, n, &agree);
    let sure: Vec<usize> = candidates
        .iter()
        .copied()
        .filter(|&e| {
            [edges[e].target, edges[e].source]
                .iter()
                .all(|k| *k == s.anchor || !unconfirmed.contains(k))
        })
        .collect();
    let (first, _) = tree_and_check(edges, &sure, n, s.anchor, &agree);
    // Where each scan lies: on that tree, else where `placed` measured it.
    let known: Vec<Option<Isometry3<f64>>> =
        first.iter().zip(placed).map(|(f, p)| f.or(*p)).collect();
    // An unconfirmed scan keeps only the edges that agree with where two of them put it; a
    // scan none of whose edges agree with another (a scan of something else) keeps none.
    let agreed: Vec<(usize, Option<Isometry3<f64>>)> = unconfirmed
        .into_iter()
        .filter(|&k| k != s.anchor)
        .map(|k| {
            let at = placed_twice(edges, &candidates, &known, k, placed[k], &agree);
            (k, at)
        })
        .collect();
    let usable: Vec<usize> = candidates
        .iter()
        .copied()
        .filter(|&e| {
            agreed.iter().all(|&(k, at)| {
                let Some((_, pose)) = edge_pose(&edges[e], &known, k) else {
                    return true;
                };
                at.zip(pose)
                    .is_some_and(|(at, pose)| agree(&(at.inverse() * pose)))
            })
        })
        .collect();
    let (mut poses, kept) = tree_and_check(edges, &usable, n, s.anchor, &agree);
    for e in kept {
        edges[e].kept = true;
    }
    // Gauss–Newton over the placed scans; from the given poses when the anchor and every
    // placed scan have one, else from the tree's.
    let placed: Vec<usize> = (0..n).filter(|&k| poses[k].is_some()).collect();
    let index = |k: usize| placed.iter().position(|&p| p == k);
    let given: Option<Vec<Isometry3<f64>>> = placed
        .iter()
        .map(|&k| relative(init, s.anchor, k))
        .collect();
    let mut nodes: Vec<Isometry3<f64>> =
        given.unwrap_or_else(|| placed.iter().map(|&k| poses[k].expect("placed")).collect());
    if let Some(a) = index(s.anchor) {
        for round in 0..=RECHECKS {
            let graph: Vec<GraphEdge> = edges
                .iter()
                .filter(|e| e.kept)
                .filter_map(|e| {
                    let r = e.registration.as_ref().ok()?;
                    let rms2 = r.inlier_rmse.powi(2).max(1e-12 * extent * extent);
                    Some(GraphEdge {
                        i: index(e.target)?,
                        j: index(e.source)?,
                        z: r.t_target_source,
                        information: r.information / rms2,
                    })
                })
                .collect();
            optimise_robust(&graph, &mut nodes, a, s.graph_iterations, GRAPH_ROUNDS);
            // An edge the tree's chain had drifted from (around a long loop) joins when it
            // agrees with the optimised poses, and the graph is solved again.
            let at = |k: usize| index(k).map(|x| nodes[x]);
            let more: Vec<usize> = usable
                .iter()
                .copied()
                .filter(|&e| !edges[e].kept)
                .filter(|&e| off_the_poses(&edges[e], at).is_some_and(|off| agree(&off)))
                .collect();
            if more.is_empty() || round == RECHECKS {
                break;
            }
            for e in more {
                edges[e].kept = true;
            }
        }
    }
    for (node, &k) in nodes.into_iter().zip(&placed) {
        poses[k] = Some(node);
    }
    poses
}

/// The scans with two or more candidate edges of which no cycle confirms one: no third scan
/// `k` with candidate edges to both ends whose poses compose to the edge's (`agree`). A scan of
/// something else is one (each registration puts it somewhere), but so can be a real scan whose
/// partners do not overlap each other, or whose right edges go to scans whose own edge is wrong;
/// [`pose_graph`] leaves out only those whose edges do not agree on where the others put it.
/// Empty when no cycle confirms anything (a few views, each pair a little off).
fn unconfirmed_scans(
    edges: &[Edge],
    candidates: &[usize],
    n: usize,
    agree: &dyn Fn(&Isometry3<f64>) -> bool,
) -> Vec<usize> {
    // z[a][b]: the pose mapping scan b into scan a, where a candidate measured it.
    let mut z: Vec<Vec<Option<Isometry3<f64>>>> = vec![vec![None; n]; n];
    let mut degree = vec![0usize; n];
    for &e in candidates {
        let (i, j) = (edges[e].target, edges[e].source);
        let t = measured(&edges[e]);
        z[i][j] = Some(t);
        z[j][i] = Some(t.inverse());
        degree[i] += 1;
        degree[j] += 1;
    }
    let mut confirmed = vec![false; n];
    for &e in candidates {
        let (i, j) = (edges[e].target, edges[e].source);
        let direct = z[i][j].expect("candidate");
        let in_cycle = (0..n).any(|k| match (z[i][k], z[k][j]) {
            (Some(a), Some(b)) => agree(&((a * b) * direct.inverse())),
            _ => false,
        });
        if in_cycle {
            (confirmed[i], confirmed[j]) = (true, true);
        }
    }
    if !confirmed.iter().any(|&c| c) {
        return Vec::new();
    }
    (0..n)
        .filter(|&k| degree[k] >= 2 && !confirmed[k])
        .collect()
}

/// A candidate edge's measured pose (scan `source` into scan `target`).
fn measured(e: &Edge) -> Isometry3<f64> {
    e.registration.as_ref().expect("candidate").t_target_source
}

/// How far edge `e`'s measured pose lies from the one its two scans' poses (`at`, `None` for
/// a scan without one) give: the identity when they agree exactly; `None` when either scan has
/// no pose.
fn off_the_poses(e: &Edge, at: impl Fn(usize) -> Option<Isometry3<f64>>) -> Option<Isometry3<f64>> {
    let (ti, tj) = (at(e.target)?, at(e.source)?);
    Some((ti.inverse() * tj) * measured(e).inverse())
}

/// When edge `e` joins scan `k` to another scan: that scan, and the pose of `k` that the edge
/// gives from that scan's pose in `poses` (`None` when it has none).
fn edge_pose(
    e: &Edge,
    poses: &[Option<Isometry3<f64>>],
    k: usize,
) -> Option<(usize, Option<Isometry3<f64>>)> {
    let (i, j, z) = (e.target, e.source, measured(e));
    match (i == k, j == k) {
        (true, false) => Some((j, poses[j].map(|tj| tj * z.inverse()))),
        (false, true) => Some((i, poses[i].map(|ti| ti * z))),
        _ => None,
    }
}

/// Where two of scan `k`'s candidate edges to scans placed at `poses` put it, when two (to
/// different scans) agree: the first such pose. `also`, when given, is one more measurement of
/// where scan `k` lies (against several scans at once, [`unplaced_against_partners`]).
fn placed_twice(
    edges: &[Edge],
    candidates: &[usize],
    poses: &[Option<Isometry3<f64>>],
    k: usize,
    also: Option<Isometry3<f64>>,
    agree: &dyn Fn(&Isometry3<f64>) -> bool,
) -> Option<Isometry3<f64>> {
    let at: Vec<(usize, Isometry3<f64>)> = candidates
        .iter()
        .filter_map(|&e| match edge_pose(&edges[e], poses, k)? {
            (partner, Some(pose)) => Some((partner, pose)),
            _ => None,
        })
        .chain(also.map(|pose| (usize::MAX, pose)))
        .collect();
    at.iter().enumerate().find_map(|(x, (a, ta))| {
        at[x + 1..]
            .iter()
            .any(|(b, tb)| a != b && agree(&(ta.inverse() * tb)))
            .then_some(*ta)
    })
}

/// The spanning tree of `usable` (Kruskal by fitness, each join voted on), the poses along it
/// from the `anchor`, and the edges kept: the tree's, and those that agree with it.
///
/// Two groups of scans are joined where the edges between them agree: of the placements of one
/// group in the other's frame that those edges give, the one whose agreeing edges sum the
/// highest fitness, through its edge of highest fitness. With scans in frames of their own, a
/// partial view is sometimes registered the wrong way round with a higher fitness than any of
/// its right edges (views turned 180° on the bunny: a pair's fitness does not tell), but the
/// wrong edges between two groups rarely agree with each other, and the right ones do.
#[allow(clippy::type_complexity)]
fn tree_and_check(
    edges: &[Edge],
    usable: &[usize],
    n: usize,
    anchor: usize,
    agree: &dyn Fn(&Isometry3<f64>) -> bool,
) -> (Vec<Option<Isometry3<f64>>>, Vec<usize>) {
    let mut order = usable.to_vec();
    order.sort_by(|&a, &b| edges[b].fitness().total_cmp(&edges[a].fitness()));
    // Each scan's group and its pose in the group's first scan's frame.
    let mut group: Vec<usize> = (0..n).collect();
    let mut within: Vec<Isometry3<f64>> = vec![Isometry3::identity(); n];
    // Where edge `e` puts the group of its source in the frame of its target's group.
    let placement = |e: usize, within: &[Isometry3<f64>]| {
        let (i, j) = (edges[e].target, edges[e].source);
        within[i] * measured(&edges[e]) * within[j].inverse()
    };
    let mut tree = Vec::new();
    for (x, &e) in order.iter().enumerate() {
        let (a, b) = (group[edges[e].target], group[edges[e].source]);
        if a == b {
            continue;
        }
        // Every remaining edge between the two groups, as a placement of b in a's frame; the
        // edges that agree with a placement vote for it with their fitness.
        let between: Vec<(usize, Isometry3<f64>)> = order[x..]
            .iter()
            .filter_map(|&f| {
                let ends = (group[edges[f].target], group[edges[f].source]);
                if ends == (a, b) {
                    Some((f, placement(f, &within)))
                } else if ends == (b, a) {
                    Some((f, placement(f, &within).inverse()))
                } else {
                    None
                }
            })
            .collect();
        let support = |p: &Isometry3<f64>| -> f64 {
            between
                .iter()
                .filter(|(_, q)| agree(&(p.inverse() * q)))
                .map(|&(f, _)| edges[f].fitness())
                .sum()
        };
        // The first of the edges (by fitness) whose placement has the most support.
        let (chosen, p) = between
            .iter()
            .map(|&(f, p)| (f, p, support(&p)))
            .fold(None::<(usize, Isometry3<f64>, f64)>, |best, c| match best {
                Some(b) if b.2 >= c.2 => Some(b),
                _ => Some(c),
            })
            .map(|(f, p, _)| (f, p))
            .expect("e is between the groups");
        for k in 0..n {
            if group[k] == b {
                group[k] = a;
                within[k] = p * within[k];
            }
        }
        tree.push(chosen);
    }
    let mut poses: Vec<Option<Isometry3<f64>>> = vec![None; n];
    poses[anchor] = Some(Isometry3::identity());
    let mut grew = true;
    while grew {
        grew = false;
        for &e in &tree {
            let (i, j, z) = (edges[e].target, edges[e].source, measured(&edges[e]));
            match (poses[i], poses[j]) {
                (Some(ti), None) => poses[j] = Some(ti * z),
                (None, Some(tj)) => poses[i] = Some(tj * z.inverse()),
                _ => continue,
            }
            grew = true;
        }
    }
    let kept = usable
        .iter()
        .copied()
        .filter(|&e| {
            let Some(off) = off_the_poses(&edges[e], |k| poses[k]) else {
                return false;
            };
            tree.contains(&e) || agree(&off)
        })
        .collect();
    (poses, kept)
}

/// The median of the scans' largest bounding-box sides.
fn median_extent(scans: &[Vec<Point3<f64>>]) -> f64 {
    let mut sides: Vec<f64> = scans
        .iter()
        .filter_map(|s| crate::geometry::cloud::bounding_box(s))
        .map(|(lo, hi)| (hi - lo).max())
        .collect();
    sides.sort_by(f64::total_cmp);
    sides.get(sides.len() / 2).copied().unwrap_or(1.0)
}

/// Scan `k` registered (from `start` in the common frame, or from nothing) against one model
/// of the other scans placed at `poses`, in that frame ([`merged_except`]).
fn against_the_others(
    scans: &[Vec<Point3<f64>>],
    poses: &[Option<Isometry3<f64>>],
    k: usize,
    start: Option<&Isometry3<f64>>,
    settings: &RegisterSettings,
) -> Result<Registration, Error> {
    let model = SdfModel::fit(&merged_except(scans, poses, Some(k)), settings)?;
    model.register(&scans[k], start, settings)
}

/// Stage 5, one round: each placed scan registered (Φ frozen, from its pose) against one model
/// of all the other placed scans in the common frame — the anchor too (a bias of its own model,
/// which every pair against it inherited, does not carry over when it is the one moved) — then
/// every pose re-expressed in the anchor's new frame.
fn joint_round(
    scans: &[Vec<Point3<f64>>],
    poses: &mut [Option<Isometry3<f64>>],
    s: &AlignSettings,
) -> Result<(), Error> {
    let settings = s.registration();
    let before = poses.to_vec();
    for k in 0..scans.len() {
        let Some(start) = before[k] else { continue };
        let r = against_the_others(scans, &before, k, Some(&start), &settings)?;
        poses[k] = Some(r.t_target_source);
    }
    if let Some(anchor) = poses[s.anchor] {
        let back = anchor.inverse();
        for p in poses.iter_mut().flatten() {
            *p = back * *p;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::se3::{exp_se3, pose_errors};
    use nalgebra::{Vector3, Vector6};
    use rand::SeedableRng;

    /// An alignment of `poses` alone (what [`Alignment::evaluate`] reads).
    fn placed_at(poses: Vec<Option<Isometry3<f64>>>) -> Alignment {
        Alignment {
            anchor: 0,
            fitness: vec![0.0; poses.len()],
            poses,
            left_out: Vec::new(),
            edges: Vec::new(),
            consensus: ConsensusOutcome::default(),
            times: AlignTimes::default(),
            time: Duration::ZERO,
        }
    }

    #[test]
    fn evaluate_measures_each_placed_scan_against_the_others_near_it() {
        // A 20 × 20 grid (spacing 0.1) on z = 0 as scan 0; scan 1 the same grid 3 cm above in
        // its own frame, placed by a pose 3 cm down (so on scan 0), and in scan 1's frame shifted
        // 1 cm more: 1 cm off scan 0; scan 2 left out; scan 3 far away.
        let grid: Vec<Point3<f64>> = (0..400)
            .map(|i| Point3::new((i % 20) as f64 * 0.1, (i / 20) as f64 * 0.1, 0.0))
            .collect();
        let up =
            |dz: f64| -> Vec<Point3<f64>> { grid.iter().map(|p| p + Vector3::z() * dz).collect() };
        let down = |dz: f64| Some(Isometry3::translation(0.0, 0.0, -dz));
        let scans = vec![grid.clone(), up(0.04), grid.clone(), up(100.0)];
        let a = placed_at(vec![down(0.0), down(0.03), None, down(0.0)]);
        let e = a.evaluate(&scans, 0.02).unwrap();
        assert!(e[2].is_none());
        let (e0, e1, e3) = (e[0].unwrap(), e[1].unwrap(), e[3].unwrap());
        assert_eq!((e0.fitness, e0.inliers, e0.source_points), (1.0, 400, 400));
        assert!((e0.inlier_rmse - 0.01).abs() < 1e-5, "{}", e0.inlier_rmse);
        assert_eq!(e1.fitness, 1.0);
        assert!((e1.inlier_rmse - 0.01).abs() < 1e-5, "{}", e1.inlier_rmse);
        // Nothing near the far scan: measured against no points, 0.
        assert_eq!((e3.fitness, e3.inliers, e3.source_points), (0.0, 0, 400));
        // At 5 mm no point of 0 or 1 is on the other.
        let tight = a.evaluate(&scans, 0.005).unwrap();
        assert_eq!(tight[0].unwrap().fitness, 0.0);
        // Refused: scans not as many as the poses, a distance that is not positive.
        assert!(matches!(
            a.evaluate(&scans[..3], 0.02),
            Err(Error::InvalidSetting { name: "scans", .. })
        ));
        assert!(matches!(
            a.evaluate(&scans, 0.0),
            Err(Error::InvalidSetting {
                name: "max_distance",
                ..
            })
        ));
    }

    /// Six scans of a blob at known poses, and edges between them that are copies of one real
    /// registration, each with the pose and fitness a test gives it.
    struct Synthetic {
        blob: Vec<Point3<f64>>,
        base: Registration,
        truth: Vec<Isometry3<f64>>,
    }

    impl Synthetic {
        fn new() -> Self {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
            let blob = crate::sim::shapes::blob(400, &mut rng);
            let settings = RegisterSettings::default();
            let base = crate::pipeline::register::register(&blob, &blob, None, &settings);
            let truth = (0..6)
                .map(|k| exp_se3(&Vector6::new(0.0, 0.0, 0.4 * k as f64, k as f64, 0.0, 0.0)))
                .collect();
            Self {
                blob,
                base: base.unwrap(),
                truth,
            }
        }

        /// The true pose of scan `j` in scan `i`'s frame.
        fn right(&self, i: usize, j: usize) -> Isometry3<f64> {
            self.truth[i].inverse() * self.truth[j]
        }

        /// Scans 0–3: two triangles, 0-1-2 and 1-2-3, every edge right (fitness 0.8).
        fn triangles(&self) -> Vec<Edge> {
            [(0, 1), (0, 2), (1, 2), (1, 3), (2, 3)]
                .map(|(i, j)| self.edge(i, j, self.right(i, j), 0.8))
                .into()
        }

        fn edge(&self, i: usize, j: usize, z: Isometry3<f64>, fitness: f64) -> Edge {
            Edge {
                target: i,
                source: j,
                registration: Ok(Registration {
                    t_target_source: z,
                    fitness,
                    ..self.base.clone()
                }),
                kept: false,
                in_free_space: None,
            }
        }
    }

    /// A wrong pose: `a` radians about x and half a unit along x away.
    fn off(a: f64) -> Isometry3<f64> {
        exp_se3(&Vector6::new(a, 0.0, 0.0, 0.5, 0.0, 0.0))
    }

    #[test]
    fn closure_pairs_join_overlapping_scans_far_apart_along_the_kept_edges() {
        // Twelve scans of one blob in one place, a ring of kept edges (k, k + 1); scan 11 lies
        // 10 blob sizes away and overlaps none. At least 3 edges apart, each scan joins at most
        // two closure pairs, each pair at least 3 kept edges apart when taken, the first
        // across the ring (6).
        let syn = Synthetic::new();
        let n = 12;
        let mut scans = vec![syn.blob.clone(); n];
        scans[n - 1] = syn.blob.iter().map(|p| p + Vector3::x() * 10.0).collect();
        let poses = vec![Some(Isometry3::identity()); n];
        let edges: Vec<Edge> = (0..n)
            .map(|k| {
                let mut e = syn.edge(k, (k + 1) % n, Isometry3::identity(), 0.8);
                e.kept = true;
                e
            })
            .collect();
        let s = AlignSettings {
            all_pairs_up_to: 4,
            closure_min_hops: 3,
            ..AlignSettings::default()
        };
        let chosen = closure_pair_list(&scans, &edges, &poses, &s).unwrap();
        let ring = |i: usize, j: usize| i.abs_diff(j).min(n - i.abs_diff(j));
        assert!(chosen.len() >= 4, "{chosen:?}");
        assert_eq!(ring(chosen[0].0, chosen[0].1), 6, "{chosen:?}");
        for k in 0..n {
            let count = chosen.iter().filter(|p| p.0 == k || p.1 == k).count();
            assert!(count <= 2, "scan {k} in {count} closure pairs: {chosen:?}");
        }
        for &(i, j) in &chosen {
            assert!(i != n - 1 && j != n - 1, "the far scan paired: {chosen:?}");
            assert!(ring(i, j) >= 3, "({i}, {j}) adjacent along the ring");
        }
        // At least 5 edges apart (the default): across the ring, then the pairs that stay 5
        // apart once it is joined.
        let five = AlignSettings {
            closure_min_hops: 5,
            ..s.clone()
        };
        let chosen = closure_pair_list(&scans, &edges, &poses, &five).unwrap();
        assert_eq!(chosen.len(), 2, "{chosen:?}");
        assert!(chosen.iter().all(|&(i, j)| ring(i, j) >= 5), "{chosen:?}");
        // Up to `all_pairs_up_to` scans every pair is registered already; 0 turns it off.
        let dense = AlignSettings::default();
        assert!(closure_pair_list(&scans, &edges, &poses, &dense)
            .unwrap()
            .is_empty());
        let off = AlignSettings {
            closure_pairs: 0,
            ..s
        };
        assert!(closure_pair_list(&scans, &edges, &poses, &off)
            .unwrap()
            .is_empty());
    }

    #[test]
    fn of_two_scans_with_as_many_points_each_is_the_target_of_about_half_its_pairs() {
        // Every pair (8 scans) and each scan with its next 3 (20 scans, a loop): with as many
        // points each, a scan is the target of half its pairs, give or take one (the earlier
        // scan always the target made scan 0 the target of all its pairs and the last of
        // none, and a bias of the one-sided objective grew along the order); a scan with more
        // points is the target whatever its place.
        for (n, per_scan, imbalance) in [(8, 7, 1), (20, 6, 2)] {
            let scans = vec![vec![Point3::origin(); 5]; n];
            let pairs = pair_list(&scans, &AlignSettings::default());
            assert_eq!(pairs.len(), n * per_scan / 2);
            for k in 0..n {
                let target = pairs.iter().filter(|p| p.0 == k).count();
                let source = pairs.iter().filter(|p| p.1 == k).count();
                assert_eq!(target + source, per_scan, "{n} scans: scan {k}");
                assert!(
                    target.abs_diff(source) <= imbalance,
                    "{n} scans: scan {k} the target of {target} pairs, the source of {source}"
                );
            }
            let mut bigger = scans.clone();
            bigger[n - 1].push(Point3::origin());
            for (i, j) in pair_list(&bigger, &AlignSettings::default()) {
                assert_ne!(
                    j,
                    n - 1,
                    "{n} scans: the scan with more points moved onto {i}"
                );
            }
        }
    }

    #[test]
    fn a_scan_whose_edges_agree_on_its_place_is_kept_and_one_whose_edges_do_not_is_left_out() {
        let t = Synthetic::new();
        let (right, edge) = (|i, j| t.right(i, j), |i, j, z, f| t.edge(i, j, z, f));
        let mut edges = t.triangles();
        edges.extend([
            // Scan 4, real: right onto 0 and 3 (which share no edge, so no cycle confirms it)
            // and wrong onto 1, with the highest fitness of all.
            edge(0, 4, right(0, 4), 0.6),
            edge(3, 4, right(3, 4), 0.6),
            edge(1, 4, right(1, 4) * off(0.3), 0.9),
            // Scan 5, of something else: registered onto 0 and onto 1, each somewhere else.
            edge(0, 5, right(0, 5) * off(0.3), 0.7),
            edge(1, 5, right(1, 5) * off(-0.4), 0.7),
        ]);
        let scans = vec![t.blob.clone(); 6];
        let s = AlignSettings::default();
        let poses = pose_graph(&scans, &mut edges, None, &[None; 6], &s);
        for (k, pose) in poses.iter().enumerate().take(5) {
            let (rot, trans) = pose_errors(&pose.expect("placed"), &right(0, k));
            assert!(rot < 1e-4 && trans < 1e-6, "scan {k}: {rot}° {trans}");
        }
        assert!(poses[5].is_none(), "the foreign scan was placed");
        assert!(!edges[7].kept, "scan 4's wrong edge was kept");
        assert!(edges[5].kept && edges[6].kept);
        // The scan left unplaced gets its pairs registered the other way round.
        assert_eq!(
            unplaced_reversed(&edges, &poses, &[]),
            Some(vec![(5, 0), (5, 1)])
        );
    }

    #[test]
    fn two_groups_are_joined_where_most_of_their_edges_agree_not_by_their_best_edge() {
        // Two triangles of right edges, 0-1-2 and 3-4-5; between them one wrong edge of the
        // highest fitness (a view registered the wrong way round) and three right ones of
        // lower fitness that agree with each other.
        let t = Synthetic::new();
        let (right, edge) = (|i, j| t.right(i, j), |i, j, z, f| t.edge(i, j, z, f));
        let mut edges: Vec<Edge> = [(0, 1), (0, 2), (1, 2), (3, 4), (3, 5), (4, 5)]
            .map(|(i, j)| edge(i, j, right(i, j), 0.95))
            .into();
        edges.extend([
            edge(2, 4, right(2, 4) * off(2.8), 0.9),
            edge(0, 3, right(0, 3), 0.6),
            edge(1, 3, right(1, 3), 0.5),
            edge(2, 5, right(2, 5), 0.5),
        ]);
        let scans = vec![t.blob.clone(); 6];
        let poses = pose_graph(
            &scans,
            &mut edges,
            None,
            &[None; 6],
            &AlignSettings::default(),
        );
        for (k, pose) in poses.iter().enumerate() {
            let (rot, trans) = pose_errors(&pose.expect("placed"), &right(0, k));
            assert!(rot < 1e-4 && trans < 1e-6, "scan {k}: {rot}° {trans}");
        }
        assert!(!edges[6].kept, "the wrong edge was kept");
        assert!(
            edges[7..].iter().all(|e| e.kept),
            "a right edge was not kept"
        );
    }

    #[test]
    fn a_measurement_against_several_scans_places_a_scan_with_one_right_edge_and_no_other() {
        let t = Synthetic::new();
        let (right, edge) = (|i, j| t.right(i, j), |i, j, z, f| t.edge(i, j, z, f));
        let mut edges = t.triangles();
        edges.extend([
            // Scan 4: right onto 0 only, wrong onto 1 and 2 (as bun270 among the bunny's).
            edge(0, 4, right(0, 4), 0.6),
            edge(1, 4, right(1, 4) * off(0.3), 0.5),
            edge(2, 4, right(2, 4) * off(-0.4), 0.5),
            // Scan 5: right onto 4 only (itself unplaced), wrong onto 1.
            edge(4, 5, right(4, 5), 0.6),
            edge(1, 5, right(1, 5) * off(0.5), 0.5),
        ]);
        let scans = vec![t.blob.clone(); 6];
        let s = AlignSettings::default();
        let graph = |measured: &[Option<Isometry3<f64>>]| {
            let mut edges = edges.clone();
            let poses = pose_graph(&scans, &mut edges, None, measured, &s);
            (poses, edges)
        };
        // Without a second measurement, no two edges of scan 4 (or 5) agree: both unplaced.
        let (poses, _) = graph(&[None; 6]);
        assert!(poses[..4].iter().all(Option::is_some));
        assert!(poses[4].is_none() && poses[5].is_none());
        // Measured where they are: each right edge agrees and places its scan (scan 5 through
        // scan 4's measured pose); the wrong edges are not kept.
        let mut measured = [None; 6];
        (measured[4], measured[5]) = (Some(right(0, 4)), Some(right(0, 5)));
        let (poses, kept) = graph(&measured);
        for (k, pose) in poses.iter().enumerate() {
            let (rot, trans) = pose_errors(&pose.expect("placed"), &right(0, k));
            assert!(rot < 1e-4 && trans < 1e-6, "scan {k}: {rot}° {trans}");
        }
        assert!(kept[5].kept && kept[8].kept);
        assert!(!kept[6].kept && !kept[7].kept && !kept[9].kept);
        // Measured somewhere else (a scan of something else): still unplaced.
        measured[4] = Some(right(0, 4) * off(0.2));
        measured[5] = None;
        let (poses, _) = graph(&measured);
        assert!(poses[4].is_none() && poses[5].is_none());
    }

    #[test]
    fn an_unplaced_scan_is_registered_against_one_model_of_its_placed_partners() {
        // Four partial views of a blob, each in its own frame; scans 0–2 placed, 3 not.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let blob = crate::sim::shapes::blob(6000, &mut rng);
        let truth: Vec<Isometry3<f64>> = (0..4)
            .map(|k| {
                let a = k as f64;
                exp_se3(&Vector6::new(
                    0.2 * a,
                    -0.1 * a,
                    0.9 * a,
                    0.3 * a,
                    0.1,
                    -0.2 * a,
                ))
            })
            .collect();
        let views: Vec<Vec<Point3<f64>>> = (0..4)
            .map(|k| {
                let d = Vector3::new((1.6 * k as f64).cos(), (1.6 * k as f64).sin(), 0.3);
                blob.iter()
                    .filter(|p| p.coords.dot(&d) > -0.2)
                    .map(|p| truth[k].inverse() * p)
                    .collect()
            })
            .collect();
        let poses: Vec<Option<Isometry3<f64>>> = (0..4)
            .map(|k| (k < 3).then(|| truth[0].inverse() * truth[k]))
            .collect();
        let failed = |i: usize, j: usize| Edge {
            target: i,
            source: j,
            registration: Err("wrong".into()),
            kept: false,
            in_free_space: None,
        };
        let edges = vec![failed(0, 3), failed(1, 3), failed(3, 2)];
        let s = AlignSettings::default();
        let mut left_out = Vec::new();
        let placed = unplaced_against_partners(&views, &edges, &poses, &mut left_out, None, &s);
        assert!(placed[..3].iter().all(Option::is_none) && left_out.is_empty());
        let (rot, trans) = pose_errors(
            &placed[3].expect("measured"),
            &(truth[0].inverse() * truth[3]),
        );
        assert!(rot < 0.5 && trans < 0.01, "{rot}° {trans}");
        // With one placed partner there is nothing to measure it against but that pair again.
        let one = [edges[0].clone()];
        let placed = unplaced_against_partners(&views, &one, &poses, &mut left_out, None, &s);
        assert!(placed.iter().all(Option::is_none) && left_out.is_empty());
        // A scan of something else lies on none of them: left out, saying so.
        let mut views = views;
        views[3] = crate::sim::shapes::bracket(3000, &mut rng);
        let placed = unplaced_against_partners(&views, &edges, &poses, &mut left_out, None, &s);
        assert!(placed.iter().all(Option::is_none));
        assert_eq!(left_out.len(), 1);
        assert_eq!(left_out[0].0, 3);
        assert!(left_out[0].1.contains("lies on none"), "{}", left_out[0].1);
    }
}
