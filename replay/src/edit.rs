//! Copies of a recording with its attachments changed: what the tests use to check that a
//! replay notices an altered model, and a way to ask what a tweaked model file would have
//! done on a recorded run (the counterfactual, item by item).

use std::path::Path;

use recording::{Event, LogWriter, RecordError};

/// Writes a copy of recording `from` to `to` (never over an existing file) with every
/// attachment's bytes passed through `change(name, bytes)`; everything else is copied as it
/// is. Returns how many attachments `change` altered.
pub fn rewrite_attachments(
    from: &Path,
    to: &Path,
    mut change: impl FnMut(&str, &[u8]) -> Option<Vec<u8>>,
) -> Result<usize, RecordError> {
    let out = recording::create_new(to)?;
    let mut w = LogWriter::new(std::io::BufWriter::new(out), to, None)?;
    let mut altered = 0;
    recording::read_file(from, |ev| {
        if let Event::Attachment {
            name,
            log_time,
            media_type,
            data,
        } = ev
            && let Some(new) = change(name, data)
        {
            altered += 1;
            return w.attach(name, log_time, media_type, &new);
        }
        w.copy_event(&ev).map(|_| ())
    })?;
    w.finish(None)?;
    Ok(altered)
}

/// `bytes` (a safetensors model) with one weight changed: the middle element of its largest
/// f32 tensor that the served map evaluates (a `decoder.*` tensor when there are any: the
/// encoder is training's only) multiplied by 1.5, plus 0.5 so a zero changes too. `None` if
/// the bytes are not a safetensors file with an f32 tensor.
pub fn alter_one_weight(bytes: &[u8]) -> Option<Vec<u8>> {
    let len = u64::from_le_bytes(bytes.get(..8)?.try_into().ok()?) as usize;
    let header: serde_json::Value = serde_json::from_slice(bytes.get(8..8 + len)?).ok()?;
    let tensors: Vec<(bool, usize, usize)> = header
        .as_object()?
        .iter()
        .filter(|(k, v)| *k != "__metadata__" && v["dtype"] == "F32")
        .filter_map(|(k, v)| {
            let o = v["data_offsets"].as_array()?;
            let (s, e) = (o.first()?.as_u64()? as usize, o.get(1)?.as_u64()? as usize);
            Some((k.starts_with("decoder"), s, e))
        })
        .collect();
    let served = tensors.iter().any(|t| t.0);
    let (_, start, end) = tensors
        .into_iter()
        .filter(|t| t.0 == served)
        .max_by_key(|(_, s, e)| e - s)?;
    let at = 8 + len + start + ((end - start) / 8) * 4;
    let mut out = bytes.to_vec();
    let v = f32::from_le_bytes(out.get(at..at + 4)?.try_into().ok()?);
    out[at..at + 4].copy_from_slice(&(v * 1.5 + 0.5).to_le_bytes());
    Some(out)
}
