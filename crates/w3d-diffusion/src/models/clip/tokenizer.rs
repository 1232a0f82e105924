//! CLIP's byte-level BPE tokenizer (transformers `CLIPTokenizer`, the "slow" Python one), as
//! Stable Diffusion 1.5 calls it: `tokenizer(text, padding="max_length", max_length=77,
//! truncation=True)`.
//!
//! The steps, in transformers' order:
//! 1. the special-token strings (`<|startoftext|>`, `<|endoftext|>`, and the pad / unknown
//!    tokens' strings) are cut out of the text as they are, case-sensitively, and map straight
//!    to their ids;
//! 2. each remaining piece is cleaned as transformers does **when `ftfy` is not installed**
//!    (its fallback, a `BasicTokenizer` without accent stripping or punctuation splitting;
//!    with ftfy, transformers instead runs `ftfy.fix_text` and collapses whitespace, which
//!    differs only on text ftfy would repair, e.g. mojibake): characters U+0000, U+FFFD and
//!    control / format / unassigned / private-use characters (Unicode category C, except tab,
//!    newline, carriage return) are dropped; tab, newline, carriage return and space
//!    separators (Zs) become spaces; CJK ideographs get a space on each side; the text is
//!    split at whitespace and each word lowercased (Unicode full lowercase mapping, as
//!    Python's `str.lower`). *Deviation:* the fallback also NFC-normalises the text; this
//!    port does not (no Unicode composition tables without a new dependency), so a letter
//!    typed as base + combining mark (e.g. `e` U+0301) tokenizes differently from its
//!    precomposed form (`é`), where transformers gives the same ids for both;
//! 3. the cleaned words, joined by single spaces, are cut by the pattern
//!    `<|startoftext|>|<|endoftext|>|'s|'t|'re|'ve|'m|'ll|'d|\p{L}+|\p{N}|[^\s\p{L}\p{N}]+`
//!    (case-insensitive; leftmost alternative first): special-token strings, contractions,
//!    runs of letters, single digits, runs of other non-space characters;
//! 4. each piece's UTF-8 bytes become symbols through CLIP's byte-to-unicode table (the 188
//!    printable Latin-1 bytes are their own character, the other 68 map to U+0100.. in byte
//!    order), the last symbol gets the end-of-word marker `</w>`, and adjacent symbols are
//!    merged by BPE, the pair of lowest merge rank first (all its non-overlapping occurrences,
//!    left to right), until no pair has a rank; a symbol missing from the vocabulary becomes
//!    the unknown token (`<|endoftext|>`). Pieces equal to `<|startoftext|>` / `<|endoftext|>`
//!    skip BPE;
//! 5. the ids are truncated to `max_length - 2`, wrapped in BOS / EOS and padded with the pad
//!    id to `max_length` (77 for SD1.5; its pad token is `<|endoftext|>`, 49407, as the BOS and
//!    EOS are 49406 and 49407).

use std::collections::HashMap;
use std::path::Path;

use regex::Regex;
use w3d_core::Error;

/// The beginning-of-text token.
pub const START_OF_TEXT: &str = "<|startoftext|>";
/// The end-of-text token (also the default unknown and pad token).
pub const END_OF_TEXT: &str = "<|endoftext|>";
/// The sequence length of SD1.x's text encoder (and the default `max_length`).
pub const CLIP_MAX_LENGTH: usize = 77;
/// transformers reads at most this many merges (`49152 - 256 - 2`, CLIP's BPE size less the
/// byte symbols and special tokens); lines after them are ignored, as there.
pub const MAX_MERGES: usize = 48_894;
/// The end-of-word marker of the last symbol of each word.
const END_OF_WORD: &str = "</w>";
/// The largest `model_max_length` accepted from `tokenizer_config.json`.
const MAX_LENGTH_LIMIT: usize = 4096;

/// The pre-tokenizer pattern (step 3 of the module docs).
const PIECES: &str = r"(?i)<\|startoftext\|>|<\|endoftext\|>|'s|'t|'re|'ve|'m|'ll|'d|\p{L}+|\p{N}|[^\s\p{L}\p{N}]+";
/// Characters the cleanup drops: NUL, U+FFFD and category C except tab, newline, return.
const DROPPED: &str = r"[\x{0}\x{FFFD}]|[\p{C}&&[^\t\n\r]]";
/// Characters the cleanup turns into a space.
const SPACES: &str = r"[\t\n\r\p{Zs}]";

/// CLIP's BPE tokenizer (see the module docs). Plain data after loading: encoding allocates
/// only per call.
#[derive(Clone, Debug)]
pub struct ClipTokenizer {
    vocab: HashMap<String, u32>,
    /// Merge rank by `"first second"` (symbols never contain a space).
    ranks: HashMap<String, u32>,
    /// The byte-to-unicode table: the symbol of each byte value.
    byte_symbols: [char; 256],
    bos: u32,
    eos: u32,
    pad: u32,
    unk: u32,
    /// Token strings cut out of the text before cleanup, longest first.
    specials: Vec<(String, u32)>,
    max_length: usize,
    pieces: Regex,
    dropped: Regex,
    spaces: Regex,
}

/// One special token as `tokenizer_config.json` / `special_tokens_map.json` write it: a string
/// or an `AddedToken` object with `content`.
fn token_string(value: &serde_json::Value) -> Option<String> {
    match value {
        serde_json::Value::String(s) => Some(s.clone()),
        serde_json::Value::Object(o) => o.get("content").and_then(|c| c.as_str()).map(str::to_string),
        _ => None,
    }
}

/// The JSON object in `path`, or `None` when the file does not exist.
fn optional_json(path: &Path) -> Result<Option<serde_json::Map<String, serde_json::Value>>, Error> {
    let text = match std::fs::read_to_string(path) {
        Ok(text) => text,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(Error::io(path, e)),
    };
    serde_json::from_str(&text).map(Some).map_err(|e| Error::format(path, "json", format!("a JSON object ({e})")))
}

/// CLIP's byte-to-unicode table (step 4 of the module docs).
fn byte_symbols() -> [char; 256] {
    let printable = |b: u32| (0x21..=0x7E).contains(&b) || (0xA1..=0xAC).contains(&b) || (0xAE..=0xFF).contains(&b);
    let mut table = ['\0'; 256];
    let mut shifted = 0u32;
    for (b, slot) in (0u32..).zip(table.iter_mut()) {
        let code = if printable(b) {
            b
        } else {
            shifted += 1;
            255 + shifted
        };
        // Every code is below U+0144, a valid scalar value.
        *slot = char::from_u32(code).unwrap_or('\u{FFFD}');
    }
    table
}

/// Whether `c` is in one of the CJK ideograph blocks transformers' `BasicTokenizer` spaces out.
fn is_cjk(c: char) -> bool {
    matches!(
        u32::from(c),
        0x4E00..=0x9FFF
            | 0x3400..=0x4DBF
            | 0x20000..=0x2A6DF
            | 0x2A700..=0x2B73F
            | 0x2B740..=0x2B81F
            | 0x2B820..=0x2CEAF
            | 0xF900..=0xFAFF
            | 0x2F800..=0x2FA1F
    )
}

/// Which special token strings a tokenizer uses.
struct Specials {
    bos: String,
    eos: String,
    pad: String,
    unk: String,
}

impl Default for Specials {
    fn default() -> Self {
        Self { bos: START_OF_TEXT.into(), eos: END_OF_TEXT.into(), pad: END_OF_TEXT.into(), unk: END_OF_TEXT.into() }
    }
}

impl ClipTokenizer {
    /// Loads a transformers `tokenizer/` folder: `vocab.json` and `merges.txt`, plus, when
    /// present, `tokenizer_config.json` (`model_max_length`, special tokens) and
    /// `special_tokens_map.json` (special tokens: `bos_token`, `eos_token`, `pad_token`,
    /// `unk_token`, as strings or `{"content": …}`). As in transformers, the config file's
    /// special tokens win when it lists `added_tokens_decoder` (files written by transformers
    /// 4.34 and later), the map's otherwise. Without a `model_max_length` the length is
    /// [`CLIP_MAX_LENGTH`].
    pub fn from_dir(dir: impl AsRef<Path>) -> Result<Self, Error> {
        let dir = dir.as_ref();
        let config_path = dir.join("tokenizer_config.json");
        let config = optional_json(&config_path)?.unwrap_or_default();
        let map = optional_json(&dir.join("special_tokens_map.json"))?.unwrap_or_default();
        let config_first = config.contains_key("added_tokens_decoder");
        let special = |key: &str| -> Option<String> {
            let (first, second) = if config_first { (&config, &map) } else { (&map, &config) };
            first.get(key).and_then(token_string).or_else(|| second.get(key).and_then(token_string))
        };
        let defaults = Specials::default();
        let specials = Specials {
            bos: special("bos_token").unwrap_or(defaults.bos),
            eos: special("eos_token").unwrap_or(defaults.eos),
            pad: special("pad_token").unwrap_or(defaults.pad),
            unk: special("unk_token").unwrap_or(defaults.unk),
        };
        let max_length = match config.get("model_max_length") {
            None | Some(serde_json::Value::Null) => CLIP_MAX_LENGTH,
            Some(v) => match v.as_u64() {
                Some(n) if (2..=MAX_LENGTH_LIMIT as u64).contains(&n) => n as usize,
                _ => {
                    return Err(Error::format(
                        &config_path,
                        "model_max_length",
                        format!("an integer in 2..={MAX_LENGTH_LIMIT} (found {v})"),
                    ));
                }
            },
        };
        Self::build(&dir.join("vocab.json"), &dir.join("merges.txt"), specials, max_length)
    }

    /// A tokenizer from CLIP's `vocab.json` (token → id) and `merges.txt` (a `#version`
    /// header line, then one merge `first second` per line, highest priority first) with
    /// CLIP's special tokens (`<|startoftext|>`, `<|endoftext|>` also as pad and unknown) and
    /// `max_length` [`CLIP_MAX_LENGTH`]. A malformed file gets an error naming it and the line.
    pub fn from_files(vocab_json: impl AsRef<Path>, merges_txt: impl AsRef<Path>) -> Result<Self, Error> {
        Self::build(vocab_json.as_ref(), merges_txt.as_ref(), Specials::default(), CLIP_MAX_LENGTH)
    }

    fn build(vocab_path: &Path, merges_path: &Path, specials: Specials, max_length: usize) -> Result<Self, Error> {
        let text = std::fs::read_to_string(vocab_path).map_err(|e| Error::io(vocab_path, e))?;
        let vocab: HashMap<String, u32> = serde_json::from_str(&text).map_err(|e| {
            Error::format(vocab_path, "vocabulary", format!("a JSON object of token → id below 2^32 ({e})"))
        })?;
        if vocab.is_empty() {
            return Err(Error::format(vocab_path, "vocabulary", "at least one token"));
        }
        let ranks = read_merges(merges_path)?;
        let id = |field: &str, token: &str| {
            vocab.get(token).copied().ok_or_else(|| {
                Error::format(vocab_path, field, format!("the special token {token:?} in the vocabulary"))
            })
        };
        let (bos, eos) = (id("bos_token", &specials.bos)?, id("eos_token", &specials.eos)?);
        let (pad, unk) = (id("pad_token", &specials.pad)?, id("unk_token", &specials.unk)?);
        let mut cut: Vec<(String, u32)> =
            vec![(specials.bos, bos), (specials.eos, eos), (specials.pad, pad), (specials.unk, unk)];
        cut.sort_by(|a, b| b.0.len().cmp(&a.0.len()).then_with(|| a.0.cmp(&b.0)));
        cut.dedup_by(|a, b| a.0 == b.0);
        cut.retain(|(s, _)| !s.is_empty());
        let regex = |pattern: &str| {
            Regex::new(pattern).map_err(|e| Error::invalid("tokenizer pattern", format!("a valid regex ({e})")))
        };
        Ok(Self {
            vocab,
            ranks,
            byte_symbols: byte_symbols(),
            bos,
            eos,
            pad,
            unk,
            specials: cut,
            max_length,
            pieces: regex(PIECES)?,
            dropped: regex(DROPPED)?,
            spaces: regex(SPACES)?,
        })
    }

    /// `max_length` ids for `text`: BOS, the BPE ids of the text (the first `max_length - 2` of
    /// them), EOS, then the pad id up to `max_length` — what transformers'
    /// `tokenizer(text, padding="max_length", max_length=max_length, truncation=True)` gives
    /// (module docs for the steps and the one known deviation). Every text is accepted.
    pub fn encode(&self, text: &str) -> Result<Vec<u32>, Error> {
        let mut ids = self.tokenize(text);
        ids.truncate(self.max_length - 2);
        let mut out = Vec::with_capacity(self.max_length);
        out.push(self.bos);
        out.append(&mut ids);
        out.push(self.eos);
        out.resize(self.max_length, self.pad);
        Ok(out)
    }

    /// The BPE ids of `text` without BOS / EOS, truncation or padding (steps 1-4 of the
    /// module docs).
    pub fn tokenize(&self, text: &str) -> Vec<u32> {
        let mut ids = Vec::new();
        let mut rest = text;
        while !rest.is_empty() {
            // The earliest special-token string in `rest` (the longest one where several start).
            let found = rest.char_indices().find_map(|(at, _)| {
                self.specials.iter().find(|(s, _)| rest[at..].starts_with(s.as_str())).map(|(s, id)| (at, s.len(), *id))
            });
            match found {
                Some((at, len, id)) => {
                    self.tokenize_piece(&rest[..at], &mut ids);
                    ids.push(id);
                    rest = &rest[at + len..];
                }
                None => {
                    self.tokenize_piece(rest, &mut ids);
                    rest = "";
                }
            }
        }
        ids
    }

    /// Steps 2-4 of the module docs on text without special-token strings.
    fn tokenize_piece(&self, text: &str, ids: &mut Vec<u32>) {
        if text.is_empty() {
            return;
        }
        let text = self.dropped.replace_all(text, "");
        let text = self.spaces.replace_all(&text, " ");
        let mut spaced = String::with_capacity(text.len());
        for c in text.chars() {
            if is_cjk(c) {
                spaced.push(' ');
                spaced.push(c);
                spaced.push(' ');
            } else {
                spaced.push(c);
            }
        }
        let words: Vec<String> = spaced.split_whitespace().map(str::to_lowercase).collect();
        let cleaned = words.join(" ");
        for piece in self.pieces.find_iter(&cleaned) {
            let piece = piece.as_str();
            if piece == START_OF_TEXT || piece == END_OF_TEXT {
                ids.push(self.id(piece));
                continue;
            }
            let symbols: String = piece.bytes().map(|b| self.byte_symbols[usize::from(b)]).collect();
            for symbol in self.bpe(&symbols) {
                ids.push(self.id(&symbol));
            }
        }
    }

    /// The vocabulary id of `token`, or the unknown token's.
    fn id(&self, token: &str) -> u32 {
        self.vocab.get(token).copied().unwrap_or(self.unk)
    }

    /// BPE of one byte-mapped word (step 4): its symbols after all ranked merges.
    fn bpe(&self, word: &str) -> Vec<String> {
        let mut symbols: Vec<String> = word.chars().map(String::from).collect();
        if let Some(last) = symbols.last_mut() {
            last.push_str(END_OF_WORD);
        }
        while symbols.len() > 1 {
            let best = symbols
                .windows(2)
                .filter_map(|pair| self.ranks.get(&format!("{} {}", pair[0], pair[1])).map(|&r| (r, pair)))
                .min_by_key(|(rank, _)| *rank)
                .map(|(_, pair)| (pair[0].clone(), pair[1].clone()));
            let Some((first, second)) = best else { break };
            let mut merged = Vec::with_capacity(symbols.len());
            let mut i = 0;
            while i < symbols.len() {
                if i + 1 < symbols.len() && symbols[i] == first && symbols[i + 1] == second {
                    merged.push(format!("{first}{second}"));
                    i += 2;
                } else {
                    merged.push(std::mem::take(&mut symbols[i]));
                    i += 1;
                }
            }
            symbols = merged;
        }
        symbols
    }

    /// The sequence length [`ClipTokenizer::encode`] returns (77 for SD1.5).
    pub fn max_length(&self) -> usize {
        self.max_length
    }

    /// Entries of the vocabulary (49 408 for SD1.5; a [`crate::ClipText`]'s `vocab_size` must
    /// exceed every id the tokenizer gives).
    pub fn vocab_size(&self) -> usize {
        self.vocab.len()
    }

    /// The id of the beginning-of-text token (49406 for SD1.5).
    pub fn bos_id(&self) -> u32 {
        self.bos
    }

    /// The id of the end-of-text token (49407 for SD1.5).
    pub fn eos_id(&self) -> u32 {
        self.eos
    }

    /// The id that pads [`ClipTokenizer::encode`]'s output (49407, `<|endoftext|>`, for SD1.x).
    pub fn pad_id(&self) -> u32 {
        self.pad
    }
}

/// The merge ranks of `merges.txt` (see [`ClipTokenizer::from_files`]): the first line is the
/// header; a later duplicate of a merge takes the later rank, as in transformers.
fn read_merges(path: &Path) -> Result<HashMap<String, u32>, Error> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let mut lines = text.trim().split('\n');
    match lines.next() {
        Some(header) if header.starts_with('#') => {}
        _ => return Err(Error::format(path, "line 1", "a `#version: …` header line")),
    }
    let mut ranks = HashMap::new();
    for (rank, line) in (0u32..).zip(lines.take(MAX_MERGES)) {
        let mut parts = line.split_whitespace();
        match (parts.next(), parts.next(), parts.next()) {
            (Some(first), Some(second), None) => {
                ranks.insert(format!("{first} {second}"), rank);
            }
            _ => {
                let field = format!("line {}", rank as usize + 2);
                return Err(Error::format(path, field, format!("two symbols separated by a space (found {line:?})")));
            }
        }
    }
    Ok(ranks)
}
