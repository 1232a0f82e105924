"""Parity fixtures of the CLIP text encoder and BPE tokenizer of crates/w3d-diffusion.

Run from the repository root: `python xtask/python/fixtures_clip_text.py` (the Python of
`cargo xtask fixtures diffusion`). Writes crates/w3d-diffusion/tests/fixtures/clip_text/:

- `tokenizer/` (vocab.json, merges.txt, special_tokens_map.json, tokenizer_config.json): a
  small vocabulary in the layout of CLIP's: the 256 byte-level base symbols in CLIP's
  byte-to-unicode order, the same 256 with the `</w>` end-of-word marker, one token per merge
  (learnt here by plain BPE training on a small corpus written below) and `<|startoftext|>`,
  `<|endoftext|>` last. Saved by transformers' `CLIPTokenizer.save_pretrained`.
- `cases.json`: `[{"text": …, "ids": […]}]`, the ids transformers' `CLIPTokenizer` gives with
  `padding="max_length", max_length=77, truncation=True` (ftfy is not installed, so the
  tokenizer's BasicTokenizer fallback cleans the text; the Rust port mirrors that fallback),
  and `pad_bang_cases.json`, the same with `pad_token="!"` (SD2's padding).
- `text_encoder/` (config.json, model.safetensors): a tiny random-weight `CLIPTextModel`
  (hidden 32, 2 layers, 4 heads, MLP 64, 77 positions, quick_gelu, norms perturbed) with
  transformers key names, and `text_encoder/io.safetensors`: `input_ids` [3, 77] (f32, the
  ids of the colour prompt, the normal prompt and "") with their `last_hidden_state`, and
  `short_ids` [1, 9] with `short_hidden` (a sequence shorter than 77).

Last written with torch 2.4.1, transformers 4.44.2 (ftfy not installed), safetensors 0.8.0.
"""

import collections
import json
import os
import sys
import tempfile

sys.path.insert(0, os.path.dirname(__file__))

import regex  # noqa: E402
import torch  # noqa: E402
from fixtures_diffusion import OUT, perturb_norms, save, state  # noqa: E402
from safetensors.torch import save_file  # noqa: E402
from transformers import CLIPTextConfig, CLIPTextModel, CLIPTokenizer  # noqa: E402

DIR = os.path.join(OUT, "clip_text")
MERGES = 400

COLOUR = "4views, multiview color"
NORMAL = "4views, multiview normal map"

CORPUS = """
4views, multiview color. 4views, multiview normal map. A multiview render of an object in
four views: front, right, back and left. The color image and the normal map of the same view
share the camera. Normal maps store unit normals as colors; the background is white.
Stable diffusion turns text into an image; the text encoder reads tokens, the tokenizer writes
them. A photo of a cat, a dog, a red car, a wooden chair and a blue teacup on a table.
High quality, detailed, sharp, realistic rendering with soft lighting and clean edges.
Views from the front and the back; views from the left and the right. Colour or color?
It's the model's view; they're multiview images we've rendered, I'm sure you'll like it,
he'd say. Numbers like 2024, 512 and 77 are split into single digits.
"""

CASES = [
    COLOUR,
    NORMAL,
    "",
    "Multiview COLOR, Normal Map",
    "a photo of a cat!!! (high-quality) -- [detailed]; 100% sharp?",
    "views 2024 and 512x512 at 3.5 steps",
    "it's they're we've I'm you'll he'd don't IT'S",
    "café crème, naïve résumé",
    "日本の猫 and 中文字",
    "emoji 🐱 cat 👍🏽 ok",
    "   extra \t whitespace\n\nand   tabs\t ",
    "a<|endoftext|>b !<|startoftext|> <|EndOfText|>",
    "zzqx unseen wordsmithery xylophone",
    "İstanbul ΣΑΣ Straße ﬁne",
    "non\u00a0breaking\u2003em\u200bzero\x00nul\ufffdrepl\u2028line\x0bvt",
    "½ ² ٣ 𝟘 Ⅻ",
    "क्षत्रिय हिन्दी",
    "don't's ''m 'LL",
    "カタカナ 한국어 ｆｕｌｌ",
    " ".join(["multiview color normal map views"] * 20),
]


def bytes_to_unicode():
    """CLIP's byte-level alphabet: printable Latin-1 bytes map to themselves, the others to
    U+0100 and up, in byte order."""
    printable = (
        list(range(ord("!"), ord("~") + 1)) + list(range(ord("¡"), ord("¬") + 1)) + list(range(ord("®"), ord("ÿ") + 1))
    )
    codes = printable[:]
    extra = 0
    for b in range(256):
        if b not in printable:
            printable.append(b)
            codes.append(256 + extra)
            extra += 1
    return dict(zip(printable, [chr(c) for c in codes]))


def train_bpe(corpus, merges):
    """Plain BPE training (most frequent adjacent pair; ties broken by the pair's text) on the
    words CLIP's pre-tokenizer cuts from the lowercased corpus."""
    byte_map = bytes_to_unicode()
    pattern = regex.compile(r"""'s|'t|'re|'ve|'m|'ll|'d|[\p{L}]+|[\p{N}]|[^\s\p{L}\p{N}]+""", regex.IGNORECASE)
    counts = collections.Counter(pattern.findall(" ".join(corpus.lower().split())))
    words = {}
    for word, n in counts.items():
        symbols = [byte_map[b] for b in word.encode("utf-8")]
        symbols[-1] += "</w>"
        words[tuple(symbols)] = n
    learnt = []
    for _ in range(merges):
        pairs = collections.Counter()
        for symbols, n in words.items():
            for a, b in zip(symbols, symbols[1:]):
                pairs[(a, b)] += n
        if not pairs:
            break
        best = min(pairs, key=lambda p: (-pairs[p], p))
        learnt.append(best)
        merged = {}
        for symbols, n in words.items():
            out, i = [], 0
            while i < len(symbols):
                if i + 1 < len(symbols) and (symbols[i], symbols[i + 1]) == best:
                    out.append(symbols[i] + symbols[i + 1])
                    i += 2
                else:
                    out.append(symbols[i])
                    i += 1
            merged[tuple(out)] = merged.get(tuple(out), 0) + n
        words = merged
    return learnt


def tokenizer_fixture():
    byte_map = bytes_to_unicode()
    base = list(byte_map.values())
    merges = train_bpe(CORPUS, MERGES)
    tokens = base + [t + "</w>" for t in base] + [a + b for a, b in merges] + ["<|startoftext|>", "<|endoftext|>"]
    vocab = {}
    for t in tokens:
        vocab.setdefault(t, len(vocab))
    with tempfile.TemporaryDirectory() as tmp:
        vocab_file = os.path.join(tmp, "vocab.json")
        merges_file = os.path.join(tmp, "merges.txt")
        with open(vocab_file, "w", encoding="utf-8") as f:
            json.dump(vocab, f, ensure_ascii=False)
        with open(merges_file, "w", encoding="utf-8") as f:
            f.write("#version: 0.2\n" + "".join(f"{a} {b}\n" for a, b in merges))
        tokenizer = CLIPTokenizer(vocab_file, merges_file, model_max_length=77)
        assert tokenizer.fix_text is None, "ftfy is installed: the fixture must use the BasicTokenizer fallback"
        tokenizer.save_pretrained(os.path.join(DIR, "tokenizer"))
        # SD2-style padding with "!" (a vocabulary token that is also a special token).
        bang = CLIPTokenizer(vocab_file, merges_file, pad_token="!", model_max_length=77)
        bang_cases = [
            {"text": t, "ids": bang(t, padding="max_length", max_length=77, truncation=True).input_ids}
            for t in ["hi!", "a cat!!! ok", "4views, multiview color"]
        ]
    cases = []
    for text in CASES:
        ids = tokenizer(text, padding="max_length", max_length=77, truncation=True).input_ids
        cases.append({"text": text, "ids": ids})
    for name, rows in [("cases.json", cases), ("pad_bang_cases.json", bang_cases)]:
        with open(os.path.join(DIR, name), "w") as f:
            f.write("[\n" + ",\n".join(json.dumps(c) for c in rows) + "\n]\n")
    return tokenizer


def encoder_fixture(tokenizer):
    d = os.path.join(DIR, "text_encoder")
    os.makedirs(d, exist_ok=True)
    vocab = len(tokenizer.get_vocab())
    config = CLIPTextConfig(
        vocab_size=vocab,
        hidden_size=32,
        intermediate_size=64,
        num_hidden_layers=2,
        num_attention_heads=4,
        max_position_embeddings=77,
        hidden_act="quick_gelu",
        bos_token_id=vocab - 2,
        eos_token_id=vocab - 1,
        pad_token_id=vocab - 1,
    )
    torch.manual_seed(3)
    model = CLIPTextModel(config).eval()
    perturb_norms(model)
    # SD1.5's text_encoder file (written by an older transformers) still holds the
    # `position_ids` buffer; keep it so the loader's handling of it is tested.
    tensors = {**state(model), "text_model.embeddings.position_ids": torch.arange(77).unsqueeze(0)}
    save_file(tensors, os.path.join(d, "model.safetensors"))
    config.save_pretrained(d)
    ids = tokenizer([COLOUR, NORMAL, ""], padding="max_length", max_length=77, truncation=True, return_tensors="pt")
    ids = ids.input_ids
    hidden = model(input_ids=ids).last_hidden_state
    short = ids[1:2, :9]
    short_hidden = model(input_ids=short).last_hidden_state
    save(
        {
            "input_ids": ids.float(),
            "last_hidden_state": hidden,
            "short_ids": short.float(),
            "short_hidden": short_hidden,
        },
        os.path.join(d, "io.safetensors"),
    )


def main():
    os.makedirs(DIR, exist_ok=True)
    tokenizer = tokenizer_fixture()
    encoder_fixture(tokenizer)
    total = sum(os.path.getsize(os.path.join(r, f)) for r, _, fs in os.walk(DIR) for f in fs)
    print(f"fixtures written to {os.path.normpath(DIR)}: {total / 1e3:.0f} kB")


if __name__ == "__main__":
    main()
