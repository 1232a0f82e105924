//! The CLIP text encoder and BPE tokenizer against transformers 4.44.2 (fixtures from
//! `xtask/python/fixtures_clip_text.py`: a small BPE vocabulary in CLIP's layout and a tiny
//! random-weight `CLIPTextModel`), plus their errors on bad input.

use std::path::Path;

use crate::common::{fixture, max_abs, max_abs_diff, tensor, test_devices, values};
use w3d_diffusion::{ClipText, ClipTextConfig, ClipTokenizer, SafetensorsFile, Tensor};

/// `(text, ids)` pairs of a cases file.
fn cases(name: &str) -> Vec<(String, Vec<u32>)> {
    let text = std::fs::read_to_string(fixture(&format!("clip_text/{name}"))).unwrap();
    let rows: Vec<serde_json::Value> = serde_json::from_str(&text).unwrap();
    rows.iter()
        .map(|r| {
            let ids = r["ids"].as_array().unwrap().iter().map(|v| v.as_u64().unwrap() as u32).collect();
            (r["text"].as_str().unwrap().to_string(), ids)
        })
        .collect()
}

/// Ids stored as f32 values `[n, t]` in the fixture.
fn stored_ids(io: &mut SafetensorsFile, key: &str) -> Vec<Vec<u32>> {
    let (v, shape) = io.read_f32(key).unwrap();
    v.chunks(shape[1]).map(|row| row.iter().map(|&x| x as u32).collect()).collect()
}

#[test]
fn tokenizer_matches_transformers() {
    let tokenizer = ClipTokenizer::from_dir(fixture("clip_text/tokenizer")).unwrap();
    assert_eq!(tokenizer.max_length(), 77);
    let all = cases("cases.json");
    assert!(all.len() >= 14);
    for (text, expected) in &all {
        assert_eq!(&tokenizer.encode(text).unwrap(), expected, "text {text:?}");
    }
    // The same ids from the two files alone (CLIP's default special tokens and length).
    let plain =
        ClipTokenizer::from_files(fixture("clip_text/tokenizer/vocab.json"), fixture("clip_text/tokenizer/merges.txt"))
            .unwrap();
    for (text, expected) in &all {
        assert_eq!(&plain.encode(text).unwrap(), expected, "text {text:?}");
    }
    println!("tokenizer: {} strings identical", all.len());
}

#[test]
fn tokenizer_pads_with_the_configured_pad_token() {
    // SD2's tokenizer pads with "!", which then also counts as a special token in the text.
    let dir = tempfile::tempdir().unwrap();
    for file in ["vocab.json", "merges.txt"] {
        std::fs::copy(fixture(&format!("clip_text/tokenizer/{file}")), dir.path().join(file)).unwrap();
    }
    std::fs::write(dir.path().join("special_tokens_map.json"), r#"{"pad_token": "!"}"#).unwrap();
    let tokenizer = ClipTokenizer::from_dir(dir.path()).unwrap();
    assert_eq!(tokenizer.pad_id(), 0);
    for (text, expected) in cases("pad_bang_cases.json") {
        assert_eq!(tokenizer.encode(&text).unwrap(), expected, "text {text:?}");
    }
}

#[test]
fn text_encoder_matches_transformers() {
    let tokenizer = ClipTokenizer::from_dir(fixture("clip_text/tokenizer")).unwrap();
    for (name, device) in test_devices() {
        let model = ClipText::from_dir(fixture("clip_text/text_encoder"), &device).unwrap();
        assert_eq!(model.config().vocab_size, tokenizer.vocab_size());
        let mut io = SafetensorsFile::open(fixture("clip_text/text_encoder/io.safetensors")).unwrap();
        let ids = stored_ids(&mut io, "input_ids");
        // The fixture's ids are our tokenizer's ids of the enhancer's three texts.
        let ours: Vec<Vec<u32>> = ["4views, multiview color", "4views, multiview normal map", ""]
            .iter()
            .map(|t| tokenizer.encode(t).unwrap())
            .collect();
        assert_eq!(ours, ids);
        let hidden = model.encode(&ours).unwrap();
        assert_eq!(hidden.dims(), [3, 77, 32]);
        let expected: Tensor<3> = tensor(&mut io, "last_hidden_state", &device);
        let scale = max_abs(expected.clone());
        let err = max_abs_diff(hidden, expected);
        let short = model.encode(&stored_ids(&mut io, "short_ids")).unwrap();
        let err_short = max_abs_diff(short, tensor(&mut io, "short_hidden", &device));
        println!("{name}: clip text max-abs error {err:.2e} (output max {scale:.2}), 9 tokens {err_short:.2e}");
        assert!(err <= 1e-4 && err_short <= 1e-4, "{name}: clip text error {err}, 9 tokens {err_short}");
    }
}

#[test]
fn text_encoder_is_causal_and_saves_round_trip() {
    let device = w3d_diffusion::default_device();
    let config = ClipTextConfig::from_file(fixture("clip_text/text_encoder/config.json")).unwrap();
    let model = ClipText::random(&config, 5, &device).unwrap();
    // Changing a later token leaves the earlier positions unchanged.
    let a = values(model.encode(&[vec![744, 10, 20, 30, 745]]).unwrap());
    let b = values(model.encode(&[vec![744, 10, 20, 99, 745]]).unwrap());
    let d = config.hidden_size;
    assert_eq!(a[..3 * d], b[..3 * d]);
    assert_ne!(a[3 * d..4 * d], b[3 * d..4 * d]);
    let dir = tempfile::tempdir().unwrap();
    model.save(dir.path()).unwrap();
    let loaded = ClipText::from_dir(dir.path(), &device).unwrap();
    assert_eq!(loaded.config(), model.config());
    assert_eq!(values(loaded.encode(&[vec![744, 10, 20, 30, 745]]).unwrap()), a);
}

#[test]
fn text_encoder_rejects_bad_token_ids() {
    let device = w3d_diffusion::default_device();
    let model = ClipText::from_dir(fixture("clip_text/text_encoder"), &device).unwrap();
    let vocab = model.config().vocab_size as u32;
    let message = |ids: &[Vec<u32>]| model.encode(ids).unwrap_err().to_string();
    let bad_id = message(&[vec![1, 2], vec![3, vocab]]);
    assert!(bad_id.contains("token_ids[1][1]") && bad_id.contains(&format!("below vocab_size {vocab}")), "{bad_id}");
    let too_long = message(&[vec![1; 78]]);
    assert!(too_long.contains("1..=77"), "{too_long}");
    assert!(message(&[]).contains("token_ids"));
    assert!(message(&[vec![]]).contains("token_ids"));
    let ragged = message(&[vec![1, 2], vec![3]]);
    assert!(ragged.contains("token_ids[1]") && ragged.contains("2 tokens"), "{ragged}");
}

#[test]
fn text_config_rejects_bad_values() {
    let base = serde_json::json!({"vocab_size": 100, "hidden_size": 32, "num_attention_heads": 4});
    assert!(ClipTextConfig::from_value(base.clone()).is_ok());
    // A full CLIPConfig: its text_config is used.
    let full = serde_json::json!({"text_config": base.clone(), "vision_config": {}});
    assert_eq!(ClipTextConfig::from_value(full).unwrap().vocab_size, 100);
    for (field, value) in [
        ("num_attention_heads", serde_json::json!(5)),
        ("vocab_size", serde_json::json!(0)),
        ("max_position_embeddings", serde_json::json!(1 << 20)),
        ("hidden_act", serde_json::json!("relu")),
    ] {
        let mut v = base.clone();
        v[field] = value;
        let err = ClipTextConfig::from_value(v).unwrap_err().to_string();
        assert!(err.contains(field), "{field}: {err}");
    }
}

/// A copy of the fixture tokenizer's two files in a temporary folder, `edit` applied to one.
fn corrupted(file: &str, edit: impl Fn(&str) -> String) -> (tempfile::TempDir, Result<ClipTokenizer, String>) {
    let dir = tempfile::tempdir().unwrap();
    for name in ["vocab.json", "merges.txt"] {
        let text = std::fs::read_to_string(fixture(&format!("clip_text/tokenizer/{name}"))).unwrap();
        let text = if name == file { edit(&text) } else { text };
        std::fs::write(dir.path().join(name), text).unwrap();
    }
    let result = ClipTokenizer::from_dir(dir.path()).map_err(|e| e.to_string());
    (dir, result)
}

fn assert_names(err: &str, dir: &Path, file: &str, what: &str) {
    let path = dir.join(file).display().to_string();
    assert!(err.contains(&path) && err.contains(what), "expected {path} and {what:?} in: {err}");
}

#[test]
fn tokenizer_rejects_corrupt_files() {
    // Truncated JSON: the serde error names line and column.
    let (dir, r) = corrupted("vocab.json", |t| t[..t.len() / 2].to_string());
    assert_names(&r.unwrap_err(), dir.path(), "vocab.json", "EOF while parsing an object at line");
    // Negative ids.
    let (dir, r) = corrupted("vocab.json", |_| r#"{"a": -1}"#.into());
    assert_names(&r.unwrap_err(), dir.path(), "vocab.json", "token → id");
    // A vocabulary without CLIP's special tokens.
    let (dir, r) = corrupted("vocab.json", |_| r#"{"a": 0}"#.into());
    assert_names(&r.unwrap_err(), dir.path(), "vocab.json", "<|startoftext|>");
    // A merge line with three symbols (line 4 of the file).
    let (dir, r) = corrupted("merges.txt", |t| {
        let mut lines: Vec<&str> = t.lines().collect();
        lines[3] = "a b c";
        lines.join("\n")
    });
    assert_names(&r.unwrap_err(), dir.path(), "merges.txt", "line 4");
    // No header line.
    let (dir, r) = corrupted("merges.txt", |t| t.lines().skip(1).collect::<Vec<_>>().join("\n"));
    assert_names(&r.unwrap_err(), dir.path(), "merges.txt", "line 1");
    // A missing file.
    let dir = tempfile::tempdir().unwrap();
    let err = ClipTokenizer::from_dir(dir.path()).unwrap_err().to_string();
    assert!(err.contains("vocab.json"), "{err}");
    // An unusable model_max_length.
    let (dir, _) = corrupted("", str::to_string);
    std::fs::write(dir.path().join("tokenizer_config.json"), r#"{"model_max_length": 1e30}"#).unwrap();
    let err = ClipTokenizer::from_dir(dir.path()).unwrap_err().to_string();
    assert_names(&err, dir.path(), "tokenizer_config.json", "model_max_length");
}
