//! Translation search by occupancy correlation: where else could the source sit, rotation fixed?
//!
//! A small global Φ of a scene is smooth. Two fragments of a room overlapping in a floor and a
//! wall can slide along them in Φ's valley: on the 3DMatch pair (redkitchen 06→00) both the SDF
//! stage and point-to-plane ICP, started from sdfreg's pose, stay 0.63–0.67 m off at 1°, where
//! fewer source points lie on the target (38 % within 5 cm) than at the true pose (45 %).
//! The detail that tells the two apart is finer than Φ.
//!
//! This stage asks, with the rotation kept, which translations lay the most source points onto
//! the target's points. Both clouds are binned into cubes of [`ShiftSearchSettings::voxel`]; every
//! pair (occupied source cube, occupied target cube) votes for their offset; each offset's score
//! is the vote sum over its 3×3×3 neighbourhood (±1 cube of tolerance). The best local maxima
//! within [`ShiftSearchSettings::radius`] are the candidates; [`search`] polishes each and keeps
//! one only if it raises the fitness by [`ShiftSearchSettings::min_gain`].
//! On the 3DMatch pair the best peak lies 2–7 cm from the needed offset (cubes of 2.5–5 cm).
//! No correspondences are formed: it is a cross-correlation of two occupancy grids, counted
//! sparsely.
//!
//! Entry points: [`occupancy_peaks`], [`search`] (the stage of [`crate::register()`]).

use nalgebra::{Isometry3, Point3, Translation3, Vector3};
use rayon::prelude::*;

use crate::geometry::cloud::transformed_f32;
use crate::geometry::tree::Tree;
use crate::pipeline::polish::PolishOutcome;
use crate::solve::measure::inlier_stats;

/// Settings of the translation search after the polish: with the rotation kept, both clouds
/// are binned into cubes and every pair of occupied cubes votes for its offset (a sparse
/// occupancy cross-correlation, no correspondences); the best peaks are polished, and one
/// replaces the pose only on a fitness gain. It finds the slide along a scene's walls that a
/// smooth Φ does not see. Lengths are normalised (fractions of the target's largest
/// bounding-box side).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ShiftSearchSettings {
    /// Offsets searched up to this far along each axis; 0 disables the search. Default 0.3.
    pub radius: f64,
    /// Cube side of the occupancy grids. Default 0.02 (the inlier distance).
    pub voxel: f64,
    /// Peaks polished and scored at most. Default 4.
    pub candidates: usize,
    /// A candidate replaces the pose only if it raises the fitness (fraction of source points
    /// within the inlier distance of a target point) by at least this much. Default 0.02.
    pub min_gain: f64,
}

impl Default for ShiftSearchSettings {
    fn default() -> Self {
        Self {
            radius: 0.3,
            voxel: 0.02,
            candidates: 4,
            min_gain: 0.02,
        }
    }
}

impl ShiftSearchSettings {
    /// Checks every field; the error names it (`shift_search.voxel`, …).
    pub fn validate(&self) -> Result<(), crate::base::error::Error> {
        use crate::base::check;
        check::non_negative("shift_search.radius", self.radius)?;
        check::positive("shift_search.voxel", self.voxel)?;
        check::in_unit_interval("shift_search.min_gain", self.min_gain)
    }
}

/// A translation found by the search.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Peak {
    /// Offset to add to the moved source points, normalised units (a multiple of the voxel).
    pub offset: Vector3<f64>,
    /// Votes within ±1 cube of the offset.
    pub score: u64,
}

/// Sorted, deduplicated cube keys of `points`.
fn cubes(points: &[[f32; 3]], voxel: f64) -> Vec<[i32; 3]> {
    let mut keys: Vec<[i32; 3]> = points
        .iter()
        .map(|p| p.map(|c| (c as f64 / voxel).floor() as i32))
        .collect();
    keys.sort_unstable();
    keys.dedup();
    keys
}

/// The best translations of the `moved` source points (already posed) onto the `target` points,
/// best first: up to `s.candidates` local maxima of the occupancy correlation that score higher
/// than the zero offset and lie more than one cube from it (nearer ones are the current basin,
/// which the polish covers). Empty when the search is disabled or nothing beats the current
/// position.
pub fn occupancy_peaks(
    moved: &[[f32; 3]],
    target: &[[f32; 3]],
    s: &ShiftSearchSettings,
) -> Vec<Peak> {
    if !(s.radius > 0.0 && s.voxel > 0.0) || s.candidates == 0 {
        return Vec::new();
    }
    let m = (s.radius / s.voxel).ceil() as i32;
    let side = (2 * m + 1) as usize;
    let index = |d: [i32; 3]| -> usize {
        ((d[0] + m) as usize * side + (d[1] + m) as usize) * side + (d[2] + m) as usize
    };
    let src = cubes(moved, s.voxel);
    let tgt = cubes(target, s.voxel);
    // Votes: target cubes are sorted by x, so each source cube scans only the slab within ±m.
    let votes = src
        .par_chunks(64)
        .fold(
            || vec![0u32; side * side * side],
            |mut acc, chunk| {
                for a in chunk {
                    let lo = tgt.partition_point(|b| b[0] < a[0] - m);
                    let hi = tgt.partition_point(|b| b[0] <= a[0] + m);
                    for b in &tgt[lo..hi] {
                        let d = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
                        if d[1].abs() <= m && d[2].abs() <= m {
                            acc[index(d)] += 1;
                        }
                    }
                }
                acc
            },
        )
        .reduce(
            || vec![0u32; side * side * side],
            |mut a, b| {
                a.iter_mut().zip(&b).for_each(|(x, y)| *x += y);
                a
            },
        );
    // Score: the vote sum over the 3×3×3 neighbourhood (integer sums: thread-independent).
    let inside = |d: [i32; 3]| d.iter().all(|c| c.abs() <= m);
    let neighbours =
        || (-1..=1).flat_map(move |i| (-1..=1).flat_map(move |j| (-1..=1).map(move |k| [i, j, k])));
    let score = |d: [i32; 3]| -> u64 {
        neighbours()
            .map(|o| [d[0] + o[0], d[1] + o[1], d[2] + o[2]])
            .filter(|&e| inside(e))
            .map(|e| votes[index(e)] as u64)
            .sum()
    };
    let all: Vec<[i32; 3]> = (-m..=m)
        .flat_map(|i| (-m..=m).flat_map(move |j| (-m..=m).map(move |k| [i, j, k])))
        .collect();
    let scores: Vec<u64> = all.par_iter().map(|&d| score(d)).collect();
    let at = |d: [i32; 3]| scores[index(d)];
    let zero = at([0, 0, 0]);
    let mut peaks: Vec<([i32; 3], u64)> = all
        .iter()
        .filter(|&&d| {
            let v = at(d);
            v > zero
                && d.iter().any(|c| c.abs() > 1)
                && neighbours()
                    .map(|o| [d[0] + o[0], d[1] + o[1], d[2] + o[2]])
                    .filter(|&e| e != d && inside(e))
                    .all(|e| at(e) <= v)
        })
        .map(|&d| (d, at(d)))
        .collect();
    // Best first; equal scores: nearer the current position first, then by key (deterministic).
    peaks.sort_by_key(|&(d, v)| {
        (
            std::cmp::Reverse(v),
            d.iter().map(|c| c * c).sum::<i32>(),
            d,
        )
    });
    peaks.truncate(s.candidates);
    peaks
        .into_iter()
        .map(|(d, v)| Peak {
            offset: Vector3::new(d[0] as f64, d[1] as f64, d[2] as f64) * s.voxel,
            score: v,
        })
        .collect()
}

/// The pose the search settles on.
pub(crate) struct Searched {
    /// The pose: a polished peak, or the input pose when none fitted clearly better.
    pub pose: Isometry3<f64>,
    /// The source points moved by [`Self::pose`] (the quality figures reuse them).
    pub moved: Vec<[f32; 3]>,
    /// Fitness and inlier RMS (normalised) at [`Self::pose`].
    pub fitness: f64,
    /// RMS distance of the inliers, normalised units.
    pub inlier_rms: f64,
    /// Peaks tried.
    pub peaks: usize,
    /// The polish of the peak taken, if one was.
    pub taken: Option<PolishOutcome>,
    /// Fitness at the input pose.
    pub start_fitness: f64,
}

/// The shift-search stage: from `pose` (unit frame, maps `source` onto the `target` points),
/// translations that lay clearly more source points within `inlier_distance` of the target,
/// each polished by `polish_from` (the polish stage from a start pose), kept on a fitness gain of
/// [`ShiftSearchSettings::min_gain`].
pub(crate) fn search(
    source: &[Point3<f64>],
    target: &[[f32; 3]],
    tree: &Tree,
    pose: &Isometry3<f64>,
    s: &ShiftSearchSettings,
    polish_from: impl Fn(&Isometry3<f64>) -> PolishOutcome,
    inlier_distance: f64,
) -> Searched {
    let thr2 = inlier_distance * inlier_distance;
    let moved = transformed_f32(source, pose);
    let (fitness, inlier_rms) = inlier_stats(tree, &moved, thr2);
    let peaks = occupancy_peaks(&moved, target, s);
    let peaks_tried = peaks.len();
    let mut out = Searched {
        pose: *pose,
        moved,
        fitness,
        inlier_rms,
        peaks: peaks_tried,
        taken: None,
        start_fitness: fitness,
    };
    let mut best = fitness + s.min_gain;
    for peak in peaks {
        let start = Translation3::from(peak.offset) * pose;
        let candidate = polish_from(&start);
        let candidate_moved = transformed_f32(source, &candidate.pose);
        let (f, rms) = inlier_stats(tree, &candidate_moved, thr2);
        if f >= best {
            best = f;
            (out.fitness, out.inlier_rms) = (f, rms);
            out.pose = candidate.pose;
            out.moved = candidate_moved;
            out.taken = Some(candidate);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    /// An L-shaped corner of three walls with a box on the floor, as f32 points.
    fn room(n: usize, rng: &mut rand_chacha::ChaCha8Rng) -> Vec<[f32; 3]> {
        use rand::Rng;
        (0..n)
            .map(|i| {
                let (u, v): (f32, f32) = (rng.random(), rng.random());
                match i % 4 {
                    0 => [u, v, 0.0],                          // floor
                    1 => [0.0, u, v * 0.5],                    // wall x = 0
                    2 => [u, 0.0, v * 0.5],                    // wall y = 0
                    _ => [0.6 + 0.1 * u, 0.5 + 0.1 * v, 0.05], // top of a box
                }
            })
            .collect()
    }

    #[test]
    fn finds_the_offset_that_lays_the_source_onto_the_target() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let target = room(8000, &mut rng);
        let shift = [0.13f32, -0.07, 0.0];
        // The source is an independent sample of the same room, moved off by `shift`.
        let moved: Vec<[f32; 3]> = room(4000, &mut rng)
            .iter()
            .map(|p| [p[0] + shift[0], p[1] + shift[1], p[2] + shift[2]])
            .collect();
        let peaks = occupancy_peaks(&moved, &target, &ShiftSearchSettings::default());
        let best = peaks.first().expect("a peak beats the zero offset");
        let needed = Vector3::new(-0.13, 0.07, 0.0);
        assert!(
            (best.offset - needed).norm() < 0.03,
            "peak {:?} vs needed {:?}",
            best.offset,
            needed
        );
    }

    #[test]
    fn nothing_beats_a_source_already_in_place() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2);
        let target = room(8000, &mut rng);
        let moved = room(4000, &mut rng);
        let peaks = occupancy_peaks(&moved, &target, &ShiftSearchSettings::default());
        assert!(peaks.is_empty(), "{:?}", peaks.first());
        let off = ShiftSearchSettings {
            radius: 0.0,
            ..Default::default()
        };
        assert!(occupancy_peaks(&moved, &target, &off).is_empty());
    }
}
