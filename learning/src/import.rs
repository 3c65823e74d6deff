//! Import of networks trained elsewhere, in the SCL authors' JSON layout:
//!
//! ```json
//! {"linear_1": [W, b], "linear_2": [W, b], "linear_3": [W, b]}
//! ```
//!
//! `W` is a list of `n_in` rows of `n_out` numbers (shape `(in, out)`, the layout the layers
//! here use), `b` a list of `n_out`. The layers, ordered by their number (which must run
//! 1, 2, … without gaps), form the decoder: `tanh` after every layer but the last. No other
//! keys are accepted. The network's input is taken to be the raw observation unless a
//! normalisation is given; whether it includes the gripper state follows from the first
//! layer's width.

use std::path::{Path, PathBuf};

use mapper::model::{
    EncoderKind, FORMAT, ModelError, ModelHeader, ModelKind, NetworkInfo, ObsInputs, TrainingInfo,
    VERSION,
};
use mapper::network::{NetworkModel, Normaliser};
use mapper::nn::gram_schmidt::GS_EPSILON;
use mapper::nn::{Dense, Mlp, lipschitz};

/// Why an import failed.
#[derive(Debug, thiserror::Error)]
pub enum ImportError {
    /// The file could not be read.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// Not JSON of the expected layout.
    #[error("{path}: {reason}")]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// The network does not fit the requested model.
    #[error("{path}: {reason}")]
    Shape {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// The resulting model failed its checks.
    #[error(transparent)]
    Model(#[from] ModelError),
}

/// What to build from imported weights.
#[derive(Debug, Clone, PartialEq)]
pub struct ImportOptions {
    /// `Scl` or `Cae`.
    pub kind: ModelKind,
    /// Joints `m`.
    pub n_joints: usize,
    /// Action dimension `d`.
    pub latent_dim: usize,
    /// Speed scale `s` (rad/s) the network's output is multiplied by.
    pub speed_scale: f64,
    /// Orthonormalise `H` (SCL).
    pub gram_schmidt: bool,
    /// Input normalisation `(mean, std)` of the observation; identity when `None`.
    pub normalisation: Option<(Vec<f64>, Vec<f64>)>,
    /// The command line, recorded in the header.
    pub command: String,
}

/// Parses the authors' JSON layout into a network (see the module docs).
pub fn parse_json(text: &str, path: &Path) -> Result<Mlp, ImportError> {
    let fmt = |reason: String| ImportError::Format {
        path: path.to_owned(),
        reason,
    };
    let value: serde_json::Value =
        serde_json::from_str(text).map_err(|e| fmt(format!("not JSON: {e}")))?;
    let obj = value
        .as_object()
        .ok_or_else(|| fmt("expected an object of layers {\"linear_1\": [W, b], …}".into()))?;
    let mut numbered = Vec::new();
    for (key, v) in obj {
        let n: usize = key
            .strip_prefix("linear_")
            .and_then(|n| n.parse().ok())
            .ok_or_else(|| {
                fmt(format!(
                    "unexpected key `{key}`; expected linear_1, linear_2, …"
                ))
            })?;
        numbered.push((n, key.clone(), v));
    }
    numbered.sort_by_key(|(n, _, _)| *n);
    if numbered.is_empty() {
        return Err(fmt("no layers".into()));
    }
    let mut layers = Vec::new();
    for (i, (n, key, v)) in numbered.iter().enumerate() {
        if *n != i + 1 {
            return Err(fmt(format!(
                "layers must be numbered 1, 2, … without gaps; found `{key}`"
            )));
        }
        let pair = v
            .as_array()
            .filter(|a| a.len() == 2)
            .ok_or_else(|| fmt(format!("`{key}` must be [W, b]")))?;
        let rows = pair[0]
            .as_array()
            .ok_or_else(|| fmt(format!("`{key}`: W must be a list of rows")))?;
        let n_in = rows.len();
        let mut w = Vec::new();
        let mut n_out = None;
        for (r, row) in rows.iter().enumerate() {
            let row = numbers(row)
                .ok_or_else(|| fmt(format!("`{key}`: W row {r} is not a list of numbers")))?;
            match n_out {
                None => n_out = Some(row.len()),
                Some(k) if k != row.len() => {
                    return Err(fmt(format!(
                        "`{key}`: W row {r} has {} values, row 0 has {k}",
                        row.len()
                    )));
                }
                Some(_) => {}
            }
            w.extend(row);
        }
        let n_out = n_out.unwrap_or(0);
        let b =
            numbers(&pair[1]).ok_or_else(|| fmt(format!("`{key}`: b is not a list of numbers")))?;
        if n_in == 0 || n_out == 0 || b.len() != n_out {
            return Err(fmt(format!(
                "`{key}`: W is ({n_in}, {n_out}) and b has {} values; expected W (in, out) and b (out)",
                b.len()
            )));
        }
        if let Some(prev) = layers.last().map(|l: &Dense| l.n_out)
            && prev != n_in
        {
            return Err(fmt(format!(
                "`{key}` takes {n_in} inputs, but the previous layer gives {prev}"
            )));
        }
        layers.push(Dense { n_in, n_out, w, b });
    }
    Ok(Mlp { layers })
}

fn numbers(v: &serde_json::Value) -> Option<Vec<f32>> {
    v.as_array()?
        .iter()
        .map(|x| x.as_f64().map(|f| f as f32).filter(|f| f.is_finite()))
        .collect()
}

/// Builds a checked model from an imported decoder. The header records the decoder's
/// Lipschitz bound (product of its exact spectral norms with the normalisation folded in).
pub fn build(decoder: Mlp, o: &ImportOptions, path: &Path) -> Result<NetworkModel, ImportError> {
    let (m, d) = (o.n_joints, o.latent_dim);
    let shape = |reason: String| ImportError::Shape {
        path: path.to_owned(),
        reason,
    };
    let extra = if o.kind == ModelKind::Cae { d } else { 0 };
    let inputs = match decoder.n_in().checked_sub(extra) {
        Some(n) if n == m + 1 => ObsInputs::JointsAndGripper,
        Some(n) if n == m => ObsInputs::Joints,
        _ => {
            return Err(shape(format!(
                "the first layer takes {} inputs; a {} decoder for {m} joints and d = {d} takes {} (q, c{}) or {} (q{})",
                decoder.n_in(),
                o.kind,
                m + 1 + extra,
                if extra > 0 { ", a" } else { "" },
                m + extra,
                if extra > 0 { ", a" } else { "" },
            )));
        }
    };
    let want_out = if o.kind == ModelKind::Cae { m } else { m * d };
    if decoder.n_out() != want_out {
        return Err(shape(format!(
            "the last layer gives {} outputs; a {} decoder for {m} joints and d = {d} gives {want_out}",
            decoder.n_out(),
            o.kind
        )));
    }
    let n_obs = inputs.width(m);
    let norm = match &o.normalisation {
        Some((mean, std)) => {
            if mean.len() != n_obs || std.len() != n_obs {
                return Err(shape(format!(
                    "the normalisation has {} means and {} scales; the input needs {n_obs}",
                    mean.len(),
                    std.len()
                )));
            }
            Normaliser::from_lists(mean, std)
        }
        None => Normaliser::identity(n_obs),
    };
    let hidden: Vec<usize> = decoder.layers[..decoder.layers.len() - 1]
        .iter()
        .map(|l| l.n_out)
        .collect();
    let mut row_scale = norm.inv_std();
    row_scale.resize(decoder.n_in(), 1.0);
    let bound = lipschitz::bound(&decoder, &row_scale);
    let header = ModelHeader {
        format: FORMAT.into(),
        version: VERSION,
        kind: o.kind,
        n_joints: m,
        latent_dim: d,
        joint_names: crate::train::joint_names(m),
        speed_scale_rad_s: o.speed_scale,
        lipschitz_bound: Some(bound),
        network: Some(NetworkInfo {
            inputs,
            input_mean: norm.mean_list(),
            input_std: norm.std_list(),
            hidden,
            gram_schmidt: o.kind == ModelKind::Scl && o.gram_schmidt,
            gs_epsilon: f64::from(GS_EPSILON),
            encoder: EncoderKind::None,
            encoder_input_mean: Vec::new(),
            encoder_input_std: Vec::new(),
            li_losses: None,
        }),
        training: TrainingInfo {
            command: o.command.clone(),
            ..TrainingInfo::default()
        },
    };
    Ok(NetworkModel::new(header, decoder, None)?)
}

/// Reads and builds in one step.
pub fn import_file(path: &Path, o: &ImportOptions) -> Result<NetworkModel, ImportError> {
    let text = std::fs::read_to_string(path).map_err(|source| ImportError::Io {
        path: path.to_owned(),
        source,
    })?;
    build(parse_json(&text, path)?, o, path)
}

/// The authors' JSON layout of a network (the inverse of [`parse_json`]).
pub fn to_json(net: &Mlp) -> String {
    let mut obj = serde_json::Map::new();
    for (i, l) in net.layers.iter().enumerate() {
        let rows: Vec<serde_json::Value> =
            l.w.chunks_exact(l.n_out)
                .map(|r| serde_json::json!(r))
                .collect();
        obj.insert(format!("linear_{}", i + 1), serde_json::json!([rows, l.b]));
    }
    serde_json::Value::Object(obj).to_string()
}

#[cfg(test)]
mod tests {
    use super::*;
    use mapper::rng::Rng;

    fn opts(kind: ModelKind) -> ImportOptions {
        ImportOptions {
            kind,
            n_joints: 6,
            latent_dim: 2,
            speed_scale: 0.5,
            gram_schmidt: true,
            normalisation: None,
            command: "test".into(),
        }
    }

    #[test]
    fn round_trip_serves_the_same_function() {
        let mut r = Rng::new(9);
        let net = Mlp::init(&[7, 16, 16, 12], &mut r);
        let json = to_json(&net);
        let back = parse_json(&json, Path::new("w.json")).unwrap();
        assert_eq!(back, net);
        let model = build(back, &opts(ModelKind::Scl), Path::new("w.json")).unwrap();
        assert_eq!(model.info().inputs, ObsInputs::JointsAndGripper);
        let bytes = model.to_bytes().unwrap();
        // Without an encoder, an SCL file with Gram-Schmidt is evaluated by projection.
        let ds = crate::demos::joint_reach(1, 1, 2);
        let any = crate::eval::AnyModel::Net(Box::new(model.clone()));
        let mse = crate::eval::reconstruction_mse(&any, Path::new("m"), &ds.val).unwrap();
        assert!(mse.is_finite() && mse > 0.0);
        let mut loaded = mapper::LoadedModel::from_bytes(&bytes, Path::new("m")).unwrap();
        loaded.expect_dims(6, 2).unwrap();
        // The served map equals GS(h(q, c)) a computed from the JSON weights in f64.
        let q = [0.1, -0.2, 0.3, 0.0, 0.5, -0.4];
        let a = [0.6, -0.3];
        let mut out = [0.0; 6];
        loaded.map.eval(&q, 0.5, &a, &mut out);
        let mut x = q.to_vec();
        x.push(0.5);
        let h = net.forward_f64(&x);
        let mut hf: Vec<f32> = h.iter().map(|v| *v as f32).collect();
        let mut norms = [0.0; 8];
        mapper::nn::gram_schmidt::orthonormalise(&mut hf, 6, 2, GS_EPSILON, &mut norms);
        for i in 0..6 {
            let e = f64::from(hf[i * 2]) * a[0] + f64::from(hf[i * 2 + 1]) * a[1];
            assert!((out[i] - e).abs() < 1e-5, "{i}: {} vs {e}", out[i]);
        }
    }

    #[test]
    fn refuses_bad_layouts_with_a_reason() {
        let p = Path::new("w.json");
        let cases = [
            ("[1, 2]", "expected an object"),
            ("{\"dense\": [[[1]], [1]]}", "unexpected key `dense`"),
            ("{\"linear_2\": [[[1]], [1]]}", "without gaps"),
            (
                "{\"linear_1\": [[[1, 2], [3]], [1, 2]]}",
                "row 1 has 1 values",
            ),
            ("{\"linear_1\": [[[1, 2]], [1]]}", "expected W (in, out)"),
            (
                "{\"linear_1\": [[[1, 2]], [1, 2]], \"linear_2\": [[[1]], [1]]}",
                "previous layer gives 2",
            ),
            (
                "{\"linear_1\": [[[1, \"x\"]], [1, 2]]}",
                "not a list of numbers",
            ),
            ("not json", "not JSON"),
        ];
        for (text, want) in cases {
            let e = parse_json(text, p).unwrap_err().to_string();
            assert!(e.contains(want) && e.contains("w.json"), "{text}: {e}");
        }
        let mut r = Rng::new(1);
        let net = Mlp::init(&[5, 8, 12], &mut r);
        let e = build(net, &opts(ModelKind::Scl), p)
            .unwrap_err()
            .to_string();
        assert!(e.contains("takes 5 inputs"), "{e}");
        let net = Mlp::init(&[7, 8, 10], &mut r);
        let e = build(net, &opts(ModelKind::Scl), p)
            .unwrap_err()
            .to_string();
        assert!(e.contains("gives 10 outputs"), "{e}");
        // A CAE decoder takes (q, c, a) and gives qdot.
        let net = Mlp::init(&[9, 8, 6], &mut r);
        let m = build(net, &opts(ModelKind::Cae), p).unwrap();
        assert_eq!(m.header().kind, ModelKind::Cae);
        assert!(!m.info().gram_schmidt);
        let ds = crate::demos::joint_reach(1, 1, 2);
        let any = crate::eval::AnyModel::Net(Box::new(m.clone()));
        let e = crate::eval::reconstruction_mse(&any, Path::new("c.safetensors"), &ds.val);
        assert!(matches!(e, Err(crate::eval::EvalError::NoEncoder(_))));
        let mut map = m.into_map();
        let mut out = [0.0; 6];
        map.eval(&[0.0; 6], 0.0, &[0.0, 0.0], &mut out);
        assert!(out.iter().all(|v| v.is_finite()));
    }
}
