//! The `.sdfm` model file: a [safetensors](https://github.com/huggingface/safetensors) file, so
//! any safetensors reader (Python's `safetensors.numpy.load_file`, …) opens it without sdfreg.
//!
//! Layout, format version 1 (all arrays little-endian, as safetensors stores them):
//!
//! | tensor | dtype | shape | meaning |
//! |---|---|---|---|
//! | `phi.params` | F32 | `[P]` | Φ's weights and biases, layer by layer: for each layer `W` (`n_out × n_in`, row-major) then `b` (`n_out`); layers 3 → width × depth → 1; then, for a local model, the corrections θ (in voxels), one per grid corner in the order of the corners' integer coordinates `(i, j, k)` sorted lexicographically (corner `(i, j, k)` sits at `h·(i, j, k)` in the unit frame) |
//! | `phi.adam_m`, `phi.adam_v` | F32 | `[P]` | the optimiser's moments (to refine Φ later exactly as an unsaved model would) |
//! | `target.points` | F32 | `[M, 3]` | the target points Φ was fitted to, in Φ's unit frame |
//! | `frame.centre` | F64 | `[3]` | the unit frame: `x_unit = (x − centre) / scale`, target units |
//! | `frame.scale` | F64 | `[1]` | |
//!
//! Metadata (safetensors' `__metadata__`): one key, `sdfreg`, whose value is a JSON object
//! (one key, so the file's bytes are the same every time the model is saved): `format` =
//! `"sdfreg-model"`, `version` = 1, `settings` = `{"mlp": …, "fit": …, "seed": …}` (the core's
//! `MlpSettings` and `FitSettings`), `adam_steps`, `rng_word_pos` (the fit's random stream,
//! a decimal string: ChaCha8 seeded by `seed ^ 0x5DF`), and `crc32` — the CRC-32 (IEEE) of the
//! compact JSON of `settings` followed by every tensor's bytes in the order of the table, as 8
//! hex digits. Φ in the unit frame is
//! `softplus_β(W x + b)` per hidden layer (β from the settings), linear last layer; a distance in
//! target units is `scale · Φ(x_unit)`. A local model ([`crate::field::local_grid`]) adds
//! `h · Σ w_c(x) θ_c`, the trilinear interpolation of the corrections at the corners of the voxel
//! holding `x`; its grid (the voxel side `h` and which corners hold a correction) follows from
//! `settings.fit.local` and the target points, so it is rebuilt on loading, not stored. Files of
//! models fitted before the local kind existed read as they are: their settings lack
//! `fit.local`, which then reads as the global kind their Φ was
//! ([`crate::LocalSettings::legacy`]).
//!
//! Reading refuses, naming the file: a file that is not safetensors or is cut short, a
//! safetensors file of something else, a newer format version, missing or misshapen tensors,
//! settings that do not parse, and any change to the bytes (checksum). A loaded model registers
//! bit-identically to the one saved.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use safetensors::tensor::{Dtype, SafeTensorError, SafeTensors, TensorView};

use crate::base::error::IoError;
use crate::field::mlp::MlpSettings;
use crate::fit::fitter::{FitterState, SdfFitter};
use crate::fit::settings::FitSettings;
use crate::geometry::cloud::Normalization;
use crate::model::sdf_model::SdfModel;
use crate::pipeline::target::FIT_SEED_SALT;

/// The `format` metadata value of a model file.
pub const FORMAT: &str = "sdfreg-model";

/// The format version this build writes, and the newest it reads.
pub const VERSION: u32 = 1;

/// The metadata key of a model file's header.
pub const METADATA_KEY: &str = "sdfreg";

/// The settings a model file records.
#[derive(serde::Serialize, serde::Deserialize)]
struct FileSettings {
    mlp: MlpSettings,
    fit: FitSettings,
    seed: u64,
}

/// The JSON object under [`METADATA_KEY`].
#[derive(serde::Serialize, serde::Deserialize)]
struct Header {
    format: String,
    version: u32,
    settings: FileSettings,
    adam_steps: i32,
    rng_word_pos: String,
    crc32: String,
}

fn bytes_f32(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

fn bytes_f64(v: &[f64]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// The tensors in file order, as (name, dtype, shape, bytes).
type Tensors = Vec<(&'static str, Dtype, Vec<usize>, Vec<u8>)>;

fn checksum(settings: &str, tensors: &Tensors) -> String {
    let mut h = crc32fast::Hasher::new();
    h.update(settings.as_bytes());
    for (_, _, _, bytes) in tensors {
        h.update(bytes);
    }
    format!("{:08x}", h.finalize())
}

impl SdfModel {
    /// The model as `.sdfm` bytes (see the module docs).
    pub fn to_bytes(&self) -> Vec<u8> {
        let state = self.fitter.state();
        let target: Vec<f32> = self.fitter.target().iter().flatten().copied().collect();
        let tensors: Tensors = vec![
            (
                "phi.params",
                Dtype::F32,
                vec![state.params.len()],
                bytes_f32(&state.params),
            ),
            (
                "phi.adam_m",
                Dtype::F32,
                vec![state.adam_m.len()],
                bytes_f32(&state.adam_m),
            ),
            (
                "phi.adam_v",
                Dtype::F32,
                vec![state.adam_v.len()],
                bytes_f32(&state.adam_v),
            ),
            (
                "target.points",
                Dtype::F32,
                vec![target.len() / 3, 3],
                bytes_f32(&target),
            ),
            (
                "frame.centre",
                Dtype::F64,
                vec![3],
                bytes_f64(self.norm.centre.as_slice()),
            ),
            (
                "frame.scale",
                Dtype::F64,
                vec![1],
                bytes_f64(&[self.norm.scale]),
            ),
        ];
        let settings = FileSettings {
            mlp: self.mlp.clone(),
            fit: self.fitter.settings().clone(),
            seed: self.seed,
        };
        let settings_json = serde_json::to_string(&settings).expect("settings serialise");
        let header = Header {
            format: FORMAT.to_string(),
            version: VERSION,
            crc32: checksum(&settings_json, &tensors),
            settings,
            adam_steps: state.adam_steps,
            rng_word_pos: state.rng_word_pos.to_string(),
        };
        let metadata = HashMap::from([(
            METADATA_KEY.to_string(),
            serde_json::to_string(&header).expect("header serialises"),
        )]);
        let views: Vec<(&str, TensorView<'_>)> = tensors
            .iter()
            .map(|(name, dtype, shape, bytes)| {
                let view = TensorView::new(*dtype, shape.clone(), bytes).expect("sizes agree");
                (*name, view)
            })
            .collect();
        safetensors::serialize(views, Some(metadata)).expect("a valid safetensors layout")
    }

    /// Writes the model to `path` (`.sdfm`, see the module docs); an existing file is replaced.
    pub fn save(&self, path: impl AsRef<Path>) -> Result<(), IoError> {
        let path = path.as_ref();
        std::fs::write(path, self.to_bytes()).map_err(|source| IoError::Io {
            path: path.into(),
            source,
        })
    }

    /// Reads a model written by [`SdfModel::save`].
    pub fn load(path: impl AsRef<Path>) -> Result<Self, IoError> {
        let path = path.as_ref();
        let bytes = std::fs::read(path).map_err(|source| IoError::Io {
            path: path.into(),
            source,
        })?;
        Self::from_bytes(&bytes, path)
    }

    /// A model from `.sdfm` bytes; `path` names them in errors.
    pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<Self, IoError> {
        decode(bytes).map_err(|reason| IoError::BadModel {
            path: PathBuf::from(path),
            reason,
        })
    }
}

/// The model in `bytes`, or what is wrong with them.
fn decode(bytes: &[u8]) -> Result<SdfModel, String> {
    let file = SafeTensors::deserialize(bytes).map_err(|e| container_error(&e))?;
    let (header, settings_json) = read_header(bytes)?;
    let tensors = read_tensors(&file)?;
    // Over the settings as the file holds them: settings that gained a field since the file was
    // written parse with its default, and must still check.
    if header.crc32 != checksum(&settings_json, &tensors) {
        return Err("corrupted: the checksum does not match the contents".into());
    }
    let f32s = |b: &[u8]| -> Vec<f32> {
        b.chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")))
            .collect()
    };
    let f64s = |b: &[u8]| -> Vec<f64> {
        b.chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes")))
            .collect()
    };
    let (centre, scale) = (f64s(&tensors[4].3), f64s(&tensors[5].3));
    if centre.len() != 3 || scale.len() != 1 || !(scale[0] > 0.0 && scale[0].is_finite()) {
        return Err("the frame is not a centre of 3 numbers and a positive scale".into());
    }
    let points = f32s(&tensors[3].3);
    if points.len() < 6 || points.iter().any(|v| !v.is_finite()) {
        return Err("`target.points` needs at least 2 finite points".into());
    }
    let settings = header.settings;
    settings
        .mlp
        .validate()
        .and(settings.fit.validate())
        .map_err(|e| format!("settings: {e}"))?;
    let target: Vec<[f32; 3]> = points.chunks_exact(3).map(|p| [p[0], p[1], p[2]]).collect();
    let mut fitter = SdfFitter::for_restore(
        target,
        &settings.mlp,
        &settings.fit,
        settings.seed ^ FIT_SEED_SALT,
    );
    let state = FitterState {
        params: f32s(&tensors[0].3),
        adam_m: f32s(&tensors[1].3),
        adam_v: f32s(&tensors[2].3),
        adam_steps: header.adam_steps,
        rng_word_pos: header
            .rng_word_pos
            .parse()
            .map_err(|_| "`rng_word_pos` is not a number".to_string())?,
    };
    let n = state.params.len();
    fitter.restore(state).ok_or_else(|| {
        format!(
            "`phi.params` holds {n} numbers; the settings' Φ (network and local grid) needs {}",
            fitter.num_params()
        )
    })?;
    if fitter
        .mlp()
        .params()
        .iter()
        .chain(fitter.field().theta())
        .any(|v| !v.is_finite())
    {
        return Err("`phi.params` holds a non-finite number".into());
    }
    Ok(SdfModel {
        norm: Normalization {
            centre: nalgebra::Vector3::new(centre[0], centre[1], centre[2]),
            scale: scale[0],
        },
        fitter,
        mlp: settings.mlp,
        seed: settings.seed,
        grid: std::sync::OnceLock::new(),
        planes: Default::default(),
        corners: Default::default(),
    })
}

/// The JSON header under [`METADATA_KEY`]: the format and the version checked first, so a
/// newer file is told apart from a damaged one.
/// The header, and the text of its `settings` as the file holds it (what the checksum covers).
fn read_header(bytes: &[u8]) -> Result<(Header, String), String> {
    let (_, header) = SafeTensors::read_metadata(bytes).map_err(|e| container_error(&e))?;
    let meta = header.metadata().clone().unwrap_or_default();
    let Some(text) = meta.get(METADATA_KEY) else {
        return Err(format!(
            "not an sdfreg model: a safetensors file without `{METADATA_KEY}` metadata"
        ));
    };
    let value: serde_json::Value =
        serde_json::from_str(text).map_err(|e| format!("metadata: {e}"))?;
    match value.get("format").and_then(|f| f.as_str()) {
        Some(FORMAT) => {}
        other => {
            return Err(format!(
                "not an sdfreg model: its format is {}",
                other.map_or("missing".to_string(), |f| format!("{f:?}"))
            ))
        }
    }
    let version = value.get("version").and_then(|v| v.as_u64()).unwrap_or(0);
    if version > VERSION as u64 {
        return Err(format!(
            "written by a newer sdfreg (model format version {version}; this one reads up to {VERSION})"
        ));
    }
    #[derive(serde::Deserialize)]
    struct RawSettings<'a> {
        #[serde(borrow)]
        settings: &'a serde_json::value::RawValue,
    }
    let raw: RawSettings<'_> = serde_json::from_str(text).map_err(|e| format!("metadata: {e}"))?;
    let header = serde_json::from_value(value).map_err(|e| format!("metadata: {e}"))?;
    Ok((header, raw.settings.get().to_string()))
}

/// The tensors of the table in the module docs, in its order, each checked for dtype and shape.
fn read_tensors(file: &SafeTensors<'_>) -> Result<Tensors, String> {
    let tensor = |name: &'static str, dtype: Dtype, cols: Option<usize>| {
        let t = file
            .tensor(name)
            .map_err(|_| format!("no tensor `{name}`"))?;
        let shape_ok = match cols {
            None => t.shape().len() == 1,
            Some(c) => t.shape().len() == 2 && t.shape()[1] == c,
        };
        if t.dtype() != dtype || !shape_ok {
            let want = cols.map_or("[N]".to_string(), |c| format!("[N, {c}]"));
            return Err(format!(
                "tensor `{name}`: expected {dtype:?} {want}, found {:?} {:?}",
                t.dtype(),
                t.shape()
            ));
        }
        Ok((name, dtype, t.shape().to_vec(), t.data().to_vec()))
    };
    Ok(vec![
        tensor("phi.params", Dtype::F32, None)?,
        tensor("phi.adam_m", Dtype::F32, None)?,
        tensor("phi.adam_v", Dtype::F32, None)?,
        tensor("target.points", Dtype::F32, Some(3))?,
        tensor("frame.centre", Dtype::F64, None)?,
        tensor("frame.scale", Dtype::F64, None)?,
    ])
}

/// What a safetensors error means for a model file.
fn container_error(e: &SafeTensorError) -> String {
    match e {
        SafeTensorError::HeaderTooSmall
        | SafeTensorError::InvalidHeaderLength
        | SafeTensorError::MetadataIncompleteBuffer => {
            format!("truncated or not a model file (safetensors: {e})")
        }
        _ => format!("not a model file (safetensors: {e})"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::RegisterSettings;
    use rand::SeedableRng;

    fn model() -> SdfModel {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
        let target = crate::sim::shapes::blob(600, &mut rng);
        let mut s = RegisterSettings::default();
        s.fit.model_prefit_steps = 100;
        SdfModel::fit(&target, &s).unwrap()
    }

    #[test]
    fn a_file_written_before_the_local_kind_loads_as_a_global_model() {
        // A dense target (Auto would make it local today), written as an earlier version did:
        // the fit settings without `local`, the checksum over the settings as written.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let target = crate::sim::shapes::blob(4000, &mut rng);
        let mut s = RegisterSettings::default();
        s.fit.model_prefit_steps = 20;
        s.fit.local.kind = crate::ModelKind::Global;
        let model = SdfModel::fit(&target, &s).unwrap();
        let bytes = model.to_bytes();
        let file = SafeTensors::deserialize(&bytes).unwrap();
        let tensors = read_tensors(&file).unwrap();
        let (_, meta) = SafeTensors::read_metadata(&bytes).unwrap();
        let text = meta.metadata().clone().unwrap()[METADATA_KEY].clone();
        let mut header: serde_json::Value = serde_json::from_str(&text).unwrap();
        header["settings"]["fit"]
            .as_object_mut()
            .unwrap()
            .remove("local");
        let settings = serde_json::to_string(&header["settings"]).unwrap();
        header["crc32"] = checksum(&settings, &tensors).into();
        let write = |header: &serde_json::Value| {
            let metadata = HashMap::from([(METADATA_KEY.to_string(), header.to_string())]);
            let views: Vec<(&str, TensorView<'_>)> = tensors
                .iter()
                .map(|(name, dtype, shape, b)| {
                    (*name, TensorView::new(*dtype, shape.clone(), b).unwrap())
                })
                .collect();
            safetensors::serialize(views, Some(metadata)).unwrap()
        };
        let loaded = SdfModel::from_bytes(&write(&header), Path::new("old.sdfm")).unwrap();
        assert_eq!(loaded.kind(), crate::ModelKind::Global);
        assert_eq!(loaded.mlp().params(), model.mlp().params());
        // A change to those settings is still caught.
        header["settings"]["fit"]["prefit_steps"] = 21.into();
        assert!(refused(&write(&header)).contains("checksum"));
    }

    fn refused(bytes: &[u8]) -> String {
        match SdfModel::from_bytes(bytes, Path::new("m.sdfm")) {
            Ok(_) => panic!("accepted"),
            Err(e) => e.to_string(),
        }
    }

    #[test]
    fn a_round_trip_is_bit_identical() {
        let m = model();
        let bytes = m.to_bytes();
        let back = SdfModel::from_bytes(&bytes, Path::new("m.sdfm")).unwrap();
        assert_eq!(back.to_bytes(), bytes);
        assert_eq!(back.fitter.state(), m.fitter.state());
        assert_eq!(back.fitter.target(), m.fitter.target());
        assert_eq!(back.norm, m.norm);
    }

    #[test]
    fn bad_files_are_refused_by_name() {
        let bytes = model().to_bytes();
        let cut = refused(&bytes[..bytes.len() - 10]);
        assert!(
            cut.starts_with("m.sdfm: ") && cut.contains("truncated"),
            "{cut}"
        );
        assert!(refused(&bytes[..5]).contains("truncated"));
        assert!(refused(b"ply\nformat ascii 1.0\n").contains("not a model file"));
        let mut flipped = bytes.clone();
        let k = bytes.len() - 20;
        flipped[k] ^= 0x40;
        assert!(
            refused(&flipped).contains("corrupted"),
            "{}",
            refused(&flipped)
        );
        // A safetensors file of something else.
        let data = [0u8; 8];
        let view = TensorView::new(Dtype::F32, vec![2], &data).unwrap();
        let foreign = safetensors::serialize([("weight", view)], None).unwrap();
        assert!(refused(&foreign).contains("not an sdfreg model"));
        // A newer version: the header's version field rewritten in place.
        let field = br#"\"version\":1,"#;
        let at = bytes.windows(field.len()).position(|w| w == field).unwrap();
        let mut newer = bytes.clone();
        newer[at + field.len() - 2] = b'9';
        let cut = refused(&bytes[..bytes.len() - 10]);
        assert!(cut.contains("truncated"), "{cut}");
        let message = refused(&newer);
        assert!(
            message.contains("newer sdfreg (model format version 9"),
            "{message}"
        );
    }
}
