//! Errors of the registration and of cloud input/output.

use std::path::PathBuf;

/// Which input cloud an error is about.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Role {
    /// The cloud that is moved (`P`).
    Source,
    /// The cloud that stays fixed and is represented by the SDF (`Q`).
    Target,
}

impl Role {
    /// The other cloud.
    pub fn other(self) -> Role {
        match self {
            Role::Source => Role::Target,
            Role::Target => Role::Source,
        }
    }
}

impl std::fmt::Display for Role {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Role::Source => "source",
            Role::Target => "target",
        })
    }
}

/// A size in an error: `0`, else four significant digits in exponent form (`1.995e-300`, not
/// 300 decimals).
fn size(v: f64) -> String {
    if v == 0.0 {
        "0".into()
    } else {
        format!("{v:.3e}")
    }
}

/// Why a registration could not be run.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// Too few points to constrain a rigid motion or fit an SDF.
    #[error("{role} cloud has {found} points; at least {min} are needed")]
    TooFewPoints {
        /// The cloud.
        role: Role,
        /// Points given.
        found: usize,
        /// Points needed.
        min: usize,
    },
    /// Too few points once the scanner's missing returns, points at exactly (0, 0, 0), are left
    /// out ([`crate::geometry::cloud::missing_returns`]).
    #[error(
        "{role} cloud has {found} points besides {missing} missing returns at exactly (0, 0, 0); \
         at least {min} are needed"
    )]
    TooFewBesidesMissingReturns {
        /// The cloud.
        role: Role,
        /// Points left.
        found: usize,
        /// Points at exactly (0, 0, 0) left out.
        missing: usize,
        /// Points needed.
        min: usize,
    },
    /// A coordinate is NaN or infinite.
    #[error("{role} cloud: point {index} has a non-finite coordinate {point:?}")]
    NonFinite {
        /// The cloud.
        role: Role,
        /// Zero-based index of the point.
        index: usize,
        /// The offending point.
        point: [f64; 3],
    },
    /// All points (nearly) coincide: there is no shape to register against.
    #[error("{role} cloud has no extent: its bounding box's largest side is {}", size(*.extent))]
    NoExtent {
        /// The cloud.
        role: Role,
        /// Largest bounding-box side, in the cloud's units.
        extent: f64,
    },
    /// The two clouds' sizes are more than 10⁹ apart: most likely they are in different units.
    /// (A far smaller source is a point in the target's 32-bit unit frame; a far larger one
    /// lies out of every field the target gives.)
    #[error(
        "{role} cloud's largest side, {}, is {} the {}'s ({}), by a factor above 1e9; are the \
         two in the same units?",
        size(*.extent),
        if .extent < .other_extent { "below" } else { "above" },
        .role.other(),
        size(*.other_extent)
    )]
    ScalesApart {
        /// The small cloud.
        role: Role,
        /// Its largest bounding-box side, in its units.
        extent: f64,
        /// The other cloud's largest bounding-box side, in its units.
        other_extent: f64,
    },
    /// A setting is out of its valid range.
    #[error("invalid setting `{name}`: {reason}")]
    InvalidSetting {
        /// Field name in the settings struct.
        name: &'static str,
        /// What was expected.
        reason: String,
    },
    /// The initial guess is not a finite rigid transform.
    #[error("initial guess is not a finite rigid transform")]
    InvalidInit,
    /// A transformation to evaluate is not a finite similarity `[s R | t]`.
    #[error(
        "transformation is not a finite similarity [s R | t] (its 3×3 block a positive scale \
         times a rotation, its last row 0 0 0 1)"
    )]
    InvalidTransformation,
    /// The worker thread pool could not be created.
    #[error("could not create the thread pool: {0}")]
    ThreadPool(String),
    /// A target mesh that cannot serve as a distance field.
    #[error("target mesh: {0}")]
    InvalidMesh(String),
    /// Aligning views needs at least two scans.
    #[error("aligning views needs at least two scans, got {found}")]
    TooFewScans {
        /// Scans given.
        found: usize,
    },
}

impl Error {
    /// The error with source and target exchanged: for a registration run the other way round
    /// ([`crate::RegisterSettings::swap_ratio`]), said of the clouds as the caller gave them.
    pub(crate) fn with_roles_swapped(self) -> Self {
        let other = Role::other;
        match self {
            Error::TooFewPoints { role, found, min } => Error::TooFewPoints {
                role: other(role),
                found,
                min,
            },
            Error::TooFewBesidesMissingReturns {
                role,
                found,
                missing,
                min,
            } => Error::TooFewBesidesMissingReturns {
                role: other(role),
                found,
                missing,
                min,
            },
            Error::NonFinite { role, index, point } => Error::NonFinite {
                role: other(role),
                index,
                point,
            },
            Error::NoExtent { role, extent } => Error::NoExtent {
                role: other(role),
                extent,
            },
            Error::ScalesApart {
                role,
                extent,
                other_extent,
            } => Error::ScalesApart {
                role: other(role),
                extent,
                other_extent,
            },
            e => e,
        }
    }

    /// The cloud the error is about, when it is about one.
    pub fn role(&self) -> Option<Role> {
        match self {
            Error::TooFewPoints { role, .. }
            | Error::TooFewBesidesMissingReturns { role, .. }
            | Error::NonFinite { role, .. }
            | Error::NoExtent { role, .. }
            | Error::ScalesApart { role, .. } => Some(*role),
            Error::InvalidMesh(_) => Some(Role::Target),
            _ => None,
        }
    }
}

/// Why a point cloud could not be read or written.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum IoError {
    /// The file could not be opened, read or created.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The system's error.
        source: std::io::Error,
    },
    /// The extension names no supported format.
    #[error("{path}: unknown point-cloud format {extension:?} (expected .ply, .pcd, .las, .laz, .e57, .xyz, .txt, .csv or .pts)")]
    UnknownFormat {
        /// The file.
        path: PathBuf,
        /// The extension found (may be empty).
        extension: String,
    },
    /// The contents do not follow the format.
    #[error("{path}{}: {message}", line.map(|l| format!(":{l}")).unwrap_or_default())]
    Parse {
        /// The file.
        path: PathBuf,
        /// One-based line number, where known.
        line: Option<usize>,
        /// What was found and what was expected.
        message: String,
    },
    /// A model file (`.sdfm`) that cannot be used: truncated, corrupted, of another program or
    /// of a newer format version.
    #[error("{path}: {reason}")]
    BadModel {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// A mesh is asked for in a format that holds no faces.
    #[error("{path}: meshes are written as .ply")]
    MeshFormat {
        /// The file.
        path: PathBuf,
    },
    /// The file holds no points.
    #[error("{path}: no points found")]
    Empty {
        /// The file.
        path: PathBuf,
    },
    /// A point has a NaN or infinite coordinate.
    #[error("{path}{}: point {index} has a non-finite coordinate", line.map(|l| format!(":{l}")).unwrap_or_default())]
    NonFinite {
        /// The file.
        path: PathBuf,
        /// One-based line number, for text formats.
        line: Option<usize>,
        /// Zero-based point index.
        index: usize,
    },
}

impl IoError {
    /// A file whose contents do not follow its format, where no line applies: `message` (what
    /// was found and what was expected) about `path`.
    pub(crate) fn parse(path: &std::path::Path, message: impl Into<String>) -> Self {
        IoError::Parse {
            path: path.to_path_buf(),
            line: None,
            message: message.into(),
        }
    }
}
