//! Tracking: a sequence of frames registered against a stored model, each from the last
//! good frame's pose ([`SdfModel::track`]).

use std::time::Instant;

use nalgebra::{Isometry3, Point3};

use crate::base::error::{Error, Role};
use crate::base::pool::in_pool;
use crate::geometry::cloud::usable;
use crate::model::sdf_model::SdfModel;
use crate::pipeline::register::{against_in_pool, check_settings};
use crate::pipeline::registration::Registration;
use crate::pipeline::settings::{RegisterSettings, MIN_POINTS};

impl SdfModel {
    /// Registers a sequence of `frames` (user units), the first from `init` (maps the frame into
    /// the target), each next one from the previous frame's pose, against the frozen Φ with
    /// `settings` — usually [`RegisterSettings::tracking`]: no multi-start, a few LM steps, a
    /// short polish. The frames run in one worker pool. A frame that fails (too few points,
    /// NaN) gives its error in its place and the next starts from the last good pose.
    ///
    /// (A constant-velocity prediction from the last two frames was tried: on the procedural
    /// sequence of the tests it fed the registrations' jitter of a few tenths of a degree along
    /// the shape's least constrained rotation back into the next start, and the error grew by
    /// half per frame from frame 28 on.)
    pub fn track<'a>(
        &self,
        frames: impl IntoIterator<Item = &'a [Point3<f64>]> + Send,
        init: &Isometry3<f64>,
        settings: &RegisterSettings,
    ) -> Result<Vec<Result<Registration, Error>>, Error> {
        check_settings(Some(init), settings)?;
        let frames: Vec<&[Point3<f64>]> = frames.into_iter().collect();
        in_pool(settings.threads, || {
            let frozen = self.frozen();
            let mut last = *init;
            frames
                .into_iter()
                .map(|frame| {
                    let start = Instant::now();
                    let r =
                        usable(frame, Role::Source, MIN_POINTS).and_then(|(frame, left_out)| {
                            let mut r = against_in_pool(
                                &self.norm,
                                &frozen,
                                &frame,
                                Some(&last),
                                settings,
                                false,
                                &|_| {},
                            )?;
                            r.source_left_out = left_out;
                            Ok(r)
                        });
                    if let Ok(r) = &r {
                        last = r.t_target_source;
                    }
                    r.map(|mut r| {
                        r.time = start.elapsed();
                        r
                    })
                })
                .collect()
        })
    }
}
