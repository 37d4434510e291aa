//! The learned initialisation of Φ's network: parameters from which the fit reaches a given
//! quality in fewer Adam steps than from the sphere ([`crate::MlpSettings::learned_init`]).
//!
//! Learned offline by Reptile (Nichol et al., 2018) on procedural objects
//! ([`crate::sim::shapes::assembly`], each turned at random; none of the evaluation's shapes):
//! from the current parameters θ, fit one new object for a pre-fit's worth of Adam steps, move θ
//! a step towards the result, repeat. Reproduce the shipped file with
//!
//! ```sh
//! cargo run --release -p sdfreg-core --example learn_init -- --out crates/sdfreg-core/src/field/learned_init.safetensors
//! ```
//!
//! (bit for bit on the same instruction set; the kernels' sums differ between AVX2 and AVX-512
//! in the last bits). The file is a safetensors file: tensor `phi.params` (F32, `[P]`, the
//! network's flat parameters, laid out as in a model file, [`crate::model::file`]) and metadata
//! key `sdfreg` holding a JSON object with `format` = `"sdfreg-learned-init"`, the architecture
//! (`width`, `depth`, `beta`) and how it was learned.

use std::sync::OnceLock;

use safetensors::tensor::{Dtype, SafeTensors};

use crate::field::mlp::Mlp;

/// The shipped initialisation (see the module docs).
const SHIPPED: &[u8] = include_bytes!("learned_init.safetensors");

/// The `format` metadata value.
pub const FORMAT: &str = "sdfreg-learned-init";

/// The metadata key.
pub const METADATA_KEY: &str = "sdfreg";

/// The tensor holding the parameters.
pub const TENSOR: &str = "phi.params";

/// A learned initialisation: the architecture it is for and its parameters.
#[derive(Clone, Debug, PartialEq)]
pub struct LearnedInit {
    /// Neurons per hidden layer.
    pub width: usize,
    /// Hidden layers.
    pub depth: usize,
    /// Softplus sharpness β.
    pub beta: f32,
    /// The network's flat parameters.
    pub params: Vec<f32>,
}

/// What the metadata says of the architecture (other keys, how it was learned, are free).
#[derive(serde::Deserialize)]
struct Header {
    format: String,
    width: usize,
    depth: usize,
    beta: f32,
}

impl LearnedInit {
    /// Reads one from safetensors bytes; `None` unless it is one, whole and consistent
    /// (format, metadata, one F32 tensor of the architecture's parameter count, all finite).
    pub fn from_bytes(bytes: &[u8]) -> Option<Self> {
        let (_, meta) = SafeTensors::read_metadata(bytes).ok()?;
        let text = meta.metadata().as_ref()?.get(METADATA_KEY)?.clone();
        let header: Header = serde_json::from_str(&text).ok()?;
        if header.format != FORMAT || header.width == 0 || header.depth == 0 {
            return None;
        }
        let file = SafeTensors::deserialize(bytes).ok()?;
        let view = file.tensor(TENSOR).ok()?;
        let n = Mlp::param_count(header.width, header.depth);
        if view.dtype() != Dtype::F32 || view.shape() != [n] {
            return None;
        }
        let params: Vec<f32> = view
            .data()
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        (params.len() == n && params.iter().all(|v| v.is_finite())).then_some(Self {
            width: header.width,
            depth: header.depth,
            beta: header.beta,
            params,
        })
    }

    /// The safetensors bytes of this initialisation, `notes` (how it was learned) added to its
    /// metadata.
    pub fn to_bytes(&self, notes: serde_json::Value) -> Vec<u8> {
        let mut header = match notes {
            serde_json::Value::Object(notes) => notes,
            _ => serde_json::Map::new(),
        };
        header.insert("format".into(), FORMAT.into());
        header.insert("width".into(), self.width.into());
        header.insert("depth".into(), self.depth.into());
        header.insert("beta".into(), self.beta.into());
        let header = serde_json::Value::Object(header);
        let bytes: Vec<u8> = self.params.iter().flat_map(|v| v.to_le_bytes()).collect();
        let view =
            safetensors::tensor::TensorView::new(Dtype::F32, vec![self.params.len()], &bytes)
                .expect("sizes agree");
        let metadata =
            std::collections::HashMap::from([(METADATA_KEY.to_string(), header.to_string())]);
        safetensors::serialize(vec![(TENSOR, view)], Some(metadata))
            .expect("a valid safetensors layout")
    }
}

/// The shipped initialisation (the crate's `field/learned_init.safetensors`).
pub fn shipped() -> Option<&'static LearnedInit> {
    static SHIPPED_INIT: OnceLock<Option<LearnedInit>> = OnceLock::new();
    SHIPPED_INIT
        .get_or_init(|| LearnedInit::from_bytes(SHIPPED))
        .as_ref()
}

/// The shipped initialisation's parameters when it is for a network of this `width`, `depth`
/// and `beta`.
pub(crate) fn shipped_for(width: usize, depth: usize, beta: f32) -> Option<&'static [f32]> {
    let init = shipped()?;
    (init.width == width && init.depth == depth && init.beta == beta)
        .then_some(init.params.as_slice())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_shipped_initialisation_is_for_the_default_network() {
        let init = LearnedInit::from_bytes(SHIPPED).expect("the shipped file reads");
        let d = crate::MlpSettings::default();
        assert_eq!(
            (init.width, init.depth, init.beta),
            (d.width, d.depth, d.beta)
        );
        assert!(shipped_for(d.width, d.depth, d.beta).is_some());
        assert!(shipped_for(64, d.depth, d.beta).is_none());
        assert!(shipped_for(d.width, d.depth, 50.0).is_none());
        // Written again, it reads the same.
        let again = LearnedInit::from_bytes(&init.to_bytes(serde_json::json!({"note": 1})));
        assert_eq!(again.as_ref(), Some(&init));
    }

    #[test]
    fn cut_changed_or_foreign_bytes_are_not_an_initialisation() {
        let init = LearnedInit::from_bytes(SHIPPED).unwrap();
        assert!(LearnedInit::from_bytes(&SHIPPED[..SHIPPED.len() - 4]).is_none());
        assert!(LearnedInit::from_bytes(b"not safetensors").is_none());
        // A network of another size under the same header's claim.
        let short = LearnedInit {
            params: init.params[1..].to_vec(),
            ..init.clone()
        };
        assert!(LearnedInit::from_bytes(&short.to_bytes(serde_json::json!({}))).is_none());
        let mut nan = init.clone();
        nan.params[7] = f32::NAN;
        assert!(LearnedInit::from_bytes(&nan.to_bytes(serde_json::json!({}))).is_none());
        // Another format's metadata.
        let mut bytes = init.to_bytes(serde_json::json!({}));
        let at = bytes
            .windows(FORMAT.len())
            .position(|w| w == FORMAT.as_bytes())
            .unwrap();
        bytes[at] = b'S';
        assert!(LearnedInit::from_bytes(&bytes).is_none());
    }
}
