//! Many views into one frame: [`align`] and its settings and result.
//!
//! The stages, each a function of its own:
//! 1. **models** — a stored model ([`SdfModel`]) of every scan that some pair registers against;
//!    a scan that cannot be fitted (too few points, no extent) is left out;
//! 2. **pairs** — pairwise registrations through those models (Φ frozen, [`register_many`]):
//!    every pair when the scans are few ([`AlignSettings::all_pairs_up_to`]), else each scan with
//!    its next [`AlignSettings::neighbours`] in order, wrapping round (a loop); from the given
//!    initial poses when there are any, else from nothing;
//! 3. **graph** — candidate edges (fitness ≥ [`AlignSettings::min_fitness`]); the spanning tree
//!    of the highest fitness gives the starting poses; a scan with several candidate edges that
//!    neither a cycle through a third scan nor the tree confirms (a scan of something else) is
//!    left out and the tree made again without it; an edge outside it is kept only when it
//!    agrees with the tree ([`AlignSettings::consistent_rotation_deg`],
//!    [`AlignSettings::consistent_translation`]); Gauss–Newton on the kept edges
//!    ([`crate::views::graph`]). A scan no kept edge joins to the anchor is left out;
//! 4. **joint refinement** — [`AlignSettings::joint_rounds`] times, each scan registered (Φ
//!    frozen, from its pose) against one model of all the other scans in the common frame, the
//!    anchor too; then every pose re-expressed in the anchor's frame.
//!
//! **Frames**: `poses[k]` maps scan `k`'s coordinates into the anchor scan's frame, user units.

use std::borrow::Cow;
use std::time::{Duration, Instant};

use nalgebra::{Isometry3, Point3};

use crate::base::check;
use crate::base::error::Error;
use crate::batch::pairs::{register_many, Pair, PairTarget};
use crate::model::sdf_model::SdfModel;
use crate::pipeline::registration::Registration;
use crate::pipeline::settings::RegisterSettings;
use crate::views::graph::{optimise_robust, GraphEdge};

/// Rounds of Cauchy weights on the pose graph's edges ([`optimise_robust`]). Measured on the
/// procedural room's loop of 8 views: plain Gauss–Newton ends 0.32° / 35 mm off at worst (one
/// confident edge pulls), 4 rounds 0.031° / 1.5 mm.
const GRAPH_ROUNDS: usize = 4;

/// Settings of [`align`].
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct AlignSettings {
    /// Every pairwise registration's settings, and the models' fits. Default
    /// [`RegisterSettings::partial_scans`] (views overlap in part).
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
    /// Joint refinement rounds (each scan against one model of all the others); 0 skips.
    /// Default 0: measured on the procedural room's loop of 8 views, the robust pose graph
    /// alone ends at 0.031° / 1.5 mm at worst and one round at 0.046° / 4.1 mm; on the bunny's
    /// 10 scans the round changed each pose by a few hundredths of a degree either way, for
    /// 40 % more time; on a room with a sparser scan it slid one view 7.7 cm along a wall.
    pub joint_rounds: usize,
    /// Worker threads for the pairs (one pair per worker) and the fits; 0 = one per core.
    pub threads: usize,
}

impl Default for AlignSettings {
    fn default() -> Self {
        Self {
            register: RegisterSettings::partial_scans(),
            anchor: 0,
            min_fitness: 0.3,
            all_pairs_up_to: 16,
            neighbours: 3,
            consistent_rotation_deg: 2.0,
            consistent_translation: 0.02,
            graph_iterations: 20,
            joint_rounds: 0,
            threads: 0,
        }
    }
}

impl AlignSettings {
    /// Checks every field; the error names it (`align.min_fitness`, …).
    pub fn validate(&self) -> Result<(), Error> {
        self.register.validate()?;
        check::fraction_below_one("align.min_fitness", self.min_fitness)?;
        check::count_at_least("align.neighbours", self.neighbours, 1)?;
        check::non_negative(
            "align.consistent_rotation_deg",
            self.consistent_rotation_deg,
        )?;
        check::non_negative("align.consistent_translation", self.consistent_translation)
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
/// frame (a turntable's angles, odometry). See the module docs.
pub fn align(
    scans: &[Vec<Point3<f64>>],
    init: Option<&[Isometry3<f64>]>,
    s: &AlignSettings,
) -> Result<Alignment, Error> {
    let start = Instant::now();
    check_input(scans, init, s)?;
    let mut times = AlignTimes::default();
    let mut clock = Instant::now();
    let mut lap = |time: &mut Duration| {
        *time = clock.elapsed();
        clock = Instant::now();
    };
    let pairs = pair_list(scans.len(), s);
    let (models, mut left_out) = fit_models(scans, &pairs, s);
    let usable = scans.len() - left_out.len();
    if usable < 2 {
        return Err(Error::TooFewScans { found: usable });
    }
    lap(&mut times.models);
    let left: Vec<usize> = left_out.iter().map(|(k, _)| *k).collect();
    let mut edges = register_pairs(scans, &models, &pairs, &left, init, s)?;
    lap(&mut times.pairs);
    let mut poses = pose_graph(scans, &mut edges, init, s);
    lap(&mut times.graph);
    for _ in 0..s.joint_rounds {
        joint_round(scans, &mut poses, s)?;
    }
    lap(&mut times.joint);
    for (k, pose) in poses.iter().enumerate() {
        if pose.is_none() && !left_out.iter().any(|(i, _)| *i == k) {
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
        times,
        time: start.elapsed(),
    })
}

/// At least two scans, valid settings, an anchor among the scans, one initial pose per scan.
fn check_input(
    scans: &[Vec<Point3<f64>>],
    init: Option<&[Isometry3<f64>]>,
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
/// next neighbours, wrapping round.
fn pair_list(n: usize, s: &AlignSettings) -> Vec<(usize, usize)> {
    if n <= s.all_pairs_up_to {
        return (0..n)
            .flat_map(|i| (i + 1..n).map(move |j| (i, j)))
            .collect();
    }
    let mut pairs: Vec<(usize, usize)> = (0..n)
        .flat_map(|i| (1..=s.neighbours.min(n - 1)).map(move |d| (i, (i + d) % n)))
        .map(|(i, j)| (i.min(j), i.max(j)))
        .collect();
    pairs.sort_unstable();
    pairs.dedup();
    pairs
}

/// Stage 1: a model of every scan some pair registers against (`None` for the others), and the
/// scans left out because they cannot be fitted.
#[allow(clippy::type_complexity)]
fn fit_models(
    scans: &[Vec<Point3<f64>>],
    pairs: &[(usize, usize)],
    s: &AlignSettings,
) -> (Vec<Option<SdfModel>>, Vec<(usize, String)>) {
    let settings = RegisterSettings {
        threads: s.threads,
        ..s.register.clone()
    };
    let mut left_out = Vec::new();
    let models = scans
        .iter()
        .enumerate()
        .map(|(k, scan)| {
            let needed = pairs.iter().any(|&(i, _)| i == k);
            // Every scan is checked: one that cannot be a target cannot be a source either.
            match SdfModel::fit(scan, &settings) {
                Ok(model) => needed.then_some(model),
                Err(e) => {
                    left_out.push((k, e.to_string()));
                    None
                }
            }
        })
        .collect();
    (models, left_out)
}

/// Stage 2: the pairwise registrations through the models (pairs whose scan was left out are
/// not tried).
fn register_pairs(
    scans: &[Vec<Point3<f64>>],
    models: &[Option<SdfModel>],
    pairs: &[(usize, usize)],
    left_out: &[usize],
    init: Option<&[Isometry3<f64>]>,
    s: &AlignSettings,
) -> Result<Vec<Edge>, Error> {
    let tried: Vec<(usize, usize)> = pairs
        .iter()
        .copied()
        .filter(|&(i, j)| models[i].is_some() && !left_out.contains(&j))
        .collect();
    let batch: Vec<Pair<'_>> = tried
        .iter()
        .map(|&(i, j)| Pair {
            source: Cow::Borrowed(&scans[j]),
            target: PairTarget::Model(models[i].as_ref().expect("filtered")),
            init: init.map(|p| p[i].inverse() * p[j]),
            seed: None,
        })
        .collect();
    let results = register_many(&batch, &s.register, s.threads)?;
    Ok(tried
        .into_iter()
        .zip(results)
        .map(|((target, source), r)| Edge {
            target,
            source,
            registration: r.map_err(|e| e.to_string()),
            kept: false,
        })
        .collect())
}

/// Stage 3: the spanning tree, the edge check and the pose graph; marks the kept edges and
/// returns each scan's pose (`None`: not joined to the anchor).
fn pose_graph(
    scans: &[Vec<Point3<f64>>],
    edges: &mut [Edge],
    init: Option<&[Isometry3<f64>]>,
    s: &AlignSettings,
) -> Vec<Option<Isometry3<f64>>> {
    let n = scans.len();
    let candidates: Vec<usize> = (0..edges.len())
        .filter(|&e| edges[e].registration.is_ok() && edges[e].fitness() >= s.min_fitness)
        .collect();
    let extent = median_extent(scans);
    let agree = |d: &Isometry3<f64>| {
        d.rotation.angle().to_degrees() <= s.consistent_rotation_deg
            && d.translation.vector.norm() <= s.consistent_translation * extent
    };
    // A first tree and check over every candidate; then again without the scans of something
    // else: several candidate edges, none confirmed by a cycle, and fewer than two kept.
    let unconfirmed = unconfirmed_scans(edges, &candidates, n, &agree);
    let (_, kept) = tree_and_check(edges, &candidates, n, s.anchor, &agree);
    let foreign: Vec<usize> = unconfirmed
        .into_iter()
        .filter(|&k| {
            kept.iter()
                .filter(|&&e| edges[e].target == k || edges[e].source == k)
                .count()
                < 2
        })
        .collect();
    let usable: Vec<usize> = candidates
        .iter()
        .copied()
        .filter(|&e| !foreign.contains(&edges[e].target) && !foreign.contains(&edges[e].source))
        .collect();
    let (mut poses, kept) = tree_and_check(edges, &usable, n, s.anchor, &agree);
    for e in kept {
        edges[e].kept = true;
    }
    // Gauss–Newton over the placed scans; from the given poses when they are all placed.
    let placed: Vec<usize> = (0..n).filter(|&k| poses[k].is_some()).collect();
    let index = |k: usize| placed.iter().position(|&p| p == k);
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
    let mut nodes: Vec<Isometry3<f64>> = placed
        .iter()
        .map(|&k| match init {
            Some(p) => p[s.anchor].inverse() * p[k],
            None => poses[k].expect("placed"),
        })
        .collect();
    if let Some(a) = index(s.anchor) {
        optimise_robust(&graph, &mut nodes, a, s.graph_iterations, GRAPH_ROUNDS);
    }
    for (node, &k) in nodes.into_iter().zip(&placed) {
        poses[k] = Some(node);
    }
    poses
}

/// The scans with two or more candidate edges of which no cycle confirms one: no third scan
/// `k` with candidate edges to both ends whose poses compose to the edge's (`agree`). A scan of
/// something else is one (each registration puts it somewhere), but so can be a real scan whose
/// partners do not overlap each other; [`pose_graph`] leaves out only those that the tree does
/// not confirm either. Empty when no cycle confirms anything (a few views, each pair a little
/// off).
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
        let t = edges[e]
            .registration
            .as_ref()
            .expect("candidate")
            .t_target_source;
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

/// The maximum spanning tree of `usable` by fitness (Kruskal), the poses along it from the
/// `anchor`, and the edges kept: the tree's, and those that agree with it.
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
    let mut component: Vec<usize> = (0..n).collect();
    fn root(c: &mut [usize], mut k: usize) -> usize {
        while c[k] != k {
            c[k] = c[c[k]];
            k = c[k];
        }
        k
    }
    let mut tree = Vec::new();
    for e in order {
        let (a, b) = (
            root(&mut component, edges[e].target),
            root(&mut component, edges[e].source),
        );
        if a != b {
            component[a] = b;
            tree.push(e);
        }
    }
    let measured = |e: &Edge| e.registration.as_ref().expect("candidate").t_target_source;
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
            let (i, j) = (edges[e].target, edges[e].source);
            let (Some(ti), Some(tj)) = (poses[i], poses[j]) else {
                return false;
            };
            tree.contains(&e) || agree(&((ti.inverse() * tj) * measured(&edges[e]).inverse()))
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

/// Stage 4, one round: each placed scan registered (Φ frozen, from its pose) against one model
/// of all the other placed scans in the common frame — the anchor too (a bias of its own model,
/// which every pair against it inherited, does not carry over when it is the one moved) — then
/// every pose re-expressed in the anchor's new frame.
fn joint_round(
    scans: &[Vec<Point3<f64>>],
    poses: &mut [Option<Isometry3<f64>>],
    s: &AlignSettings,
) -> Result<(), Error> {
    let settings = RegisterSettings {
        threads: s.threads,
        ..s.register.clone()
    };
    let before = poses.to_vec();
    for k in 0..scans.len() {
        let Some(start) = before[k] else { continue };
        let others = merged_except(scans, &before, Some(k));
        let model = SdfModel::fit(&others, &settings)?;
        let r = model.register(&scans[k], Some(&start), &settings)?;
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
