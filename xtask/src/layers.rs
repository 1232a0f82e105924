//! `cargo xtask layers`: the import-layering and circle check over every package's `src/`.
//!
//! **Scope.** Every package source tree of the workspace: `crates/*/src` and `xtask/src`. Each
//! of `src/lib.rs` and `src/main.rs` that exists is the root of its own module tree (a package
//! with both is checked as two trees). The tree follows `mod x;` declarations (`x.rs` or
//! `x/mod.rs` beside a `lib.rs` / `main.rs` / `mod.rs` file, in the `foo/` folder for a file
//! `foo.rs`, or a `#[path]` attribute) and inline `mod x { … }` blocks; an inline module belongs
//! to the file that contains it. Comments, doc comments, string, char and raw-string literals
//! are skipped by a small lexer, so paths in them count for nothing.
//!
//! **Declared order.** In each file (or inline module) that declares submodules, the `mod`
//! declarations, with their visibility, attributes (`#[cfg(feature = "train")]`) and doc
//! comments, form *groups*: runs of declarations on consecutive lines; a blank line, a `//`
//! comment line or any other item between two declarations starts a new group (rustfmt sorts
//! `mod` lines alphabetically only within such a run, so the runs are the only order that
//! survives formatting). The groups are layers listed **bottom-up**: the first group is the
//! lowest layer. Test modules (`mod tests { … }`, `#[cfg(test)] mod tests;`: any module named
//! `tests`) take no part in the layering: their imports count as their declaring file's
//! imports, and an import of one counts as an import of its parent. Other `#[cfg(test)]`
//! modules (shared test helpers) are layered like any module. Inline modules inside function
//! or macro bodies (`mod $name { … }` in `macro_rules!`) are likewise transparent: they only
//! make `super` resolve as the compiler does.
//!
//! **Imports.** Every path in code that begins with `crate::`, `super::` or `self::` (and
//! `$crate::`): `use` trees with braces, nesting, `self`, globs and renames (`pub use`,
//! `pub(crate) use` alike), and qualified paths inside expressions and types
//! (`crate::a::b::f(x)`). `pub(in crate::a)` visibilities are not imports. Each path resolves to
//! the deepest module of the tree it names (`crate::a::B` → module `a`; `super` inside an inline
//! module is its enclosing module); the import's target is that module's file. Imports of a
//! file's own modules are ignored, and so are paths without those prefixes (`pub use
//! child::X;` in a parent, external crates).
//!
//! **Upward imports.** File F (module M) imports module N; P is the deepest common ancestor of
//! M and N. If N is P, M imports something an ancestor's own file defines or re-exports: a
//! violation (parents declare and re-export, children do not reach back up). If M is P (a parent
//! importing a descendant) the import is fine. Otherwise A and B are the children of P on the
//! ways to M and N: B in a later group of P's declarations than A is a violation (group numbers
//! in messages count from 1); the same group is allowed. Each (importing file, imported module)
//! pair is reported once, at its first line.
//!
//! **Circles.** Every strongly connected component of two or more files of the import graph is a
//! violation, reported as one cycle `a.rs:L → b.rs:L → a.rs` where each `file:L` is the first
//! line of that file importing the next one (an import written in an out-of-line `tests` file
//! shows that file and line in parentheses).
//!
//! Output: per tree one summary line (files, import edges between distinct files, levels: the
//! longest import chain, level 0 being a file that imports nothing of its crate, the files of
//! a circle sharing one level), with `--verbose` the files of each level, then each violation
//! as `path/to/file.rs:LINE: message` with the path relative to the checked root. Any
//! violation fails the command.

use std::collections::{BTreeMap, BTreeSet, HashMap, VecDeque};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// A lexical token of Rust source: comments are dropped, literals keep only what the checker
/// needs (the text of string literals, for `#[path = "…"]`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Tok {
    /// An identifier or keyword (a raw identifier `r#x` as `x`).
    Ident(String),
    /// `::`.
    PathSep,
    /// Any other single punctuation character.
    Punct(char),
    /// A string literal's contents (escapes left as written).
    Str(String),
    /// A char, byte or number literal, or a lifetime.
    Lit,
}

/// A token and the 1-based line it starts on.
#[derive(Clone, Debug)]
pub struct Token {
    /// The token.
    pub tok: Tok,
    /// Its line, from 1.
    pub line: usize,
}

fn is_ident_start(c: char) -> bool {
    c.is_alphabetic() || c == '_'
}

fn is_ident_continue(c: char) -> bool {
    c.is_alphanumeric() || c == '_'
}

/// Splits Rust source into tokens, skipping whitespace, line and (nested) block comments, doc
/// comments included.
pub fn lex(src: &str) -> Vec<Token> {
    let c: Vec<char> = src.chars().collect();
    let at = |i: usize| c.get(i).copied().unwrap_or('\0');
    let mut out = Vec::new();
    let (mut i, mut line) = (0usize, 1usize);
    // Advances over c[from..to], counting newlines.
    let count = |from: usize, to: usize, line: &mut usize| {
        *line += c[from..to.min(c.len())].iter().filter(|&&ch| ch == '\n').count();
    };
    while i < c.len() {
        let ch = c[i];
        let start_line = line;
        if ch == '\n' {
            line += 1;
            i += 1;
        } else if ch.is_whitespace() {
            i += 1;
        } else if ch == '/' && at(i + 1) == '/' {
            while i < c.len() && c[i] != '\n' {
                i += 1;
            }
        } else if ch == '/' && at(i + 1) == '*' {
            let (mut depth, mut j) = (1, i + 2);
            while j < c.len() && depth > 0 {
                if c[j] == '/' && at(j + 1) == '*' {
                    depth += 1;
                    j += 2;
                } else if c[j] == '*' && at(j + 1) == '/' {
                    depth -= 1;
                    j += 2;
                } else {
                    j += 1;
                }
            }
            count(i, j, &mut line);
            i = j;
        } else if is_ident_start(ch) {
            let mut j = i;
            while j < c.len() && is_ident_continue(c[j]) {
                j += 1;
            }
            let word: String = c[i..j].iter().collect();
            let raw_prefix = matches!(word.as_str(), "r" | "br" | "cr");
            if raw_prefix && (at(j) == '"' || (at(j) == '#' && matches!(at(j + 1), '#' | '"'))) {
                // Raw string: r#"…"#.
                let mut hashes = 0;
                while at(j) == '#' {
                    hashes += 1;
                    j += 1;
                }
                j += 1; // the opening quote
                let body = j;
                loop {
                    if j >= c.len() {
                        break;
                    }
                    if c[j] == '"' && (1..=hashes).all(|h| at(j + h) == '#') {
                        break;
                    }
                    j += 1;
                }
                let text: String = c[body..j.min(c.len())].iter().collect();
                j = (j + 1 + hashes).min(c.len());
                count(i, j, &mut line);
                out.push(Token { tok: Tok::Str(text), line: start_line });
                i = j;
            } else if word == "r" && at(j) == '#' && is_ident_start(at(j + 1)) {
                // Raw identifier r#name.
                let mut k = j + 1;
                while k < c.len() && is_ident_continue(c[k]) {
                    k += 1;
                }
                out.push(Token { tok: Tok::Ident(c[j + 1..k].iter().collect()), line });
                i = k;
            } else if matches!(word.as_str(), "b" | "c") && at(j) == '"' {
                i = j; // the string itself is lexed next
            } else if word == "b" && at(j) == '\'' {
                i = j; // byte char literal, lexed next
            } else {
                out.push(Token { tok: Tok::Ident(word), line });
                i = j;
            }
        } else if ch == '"' {
            let mut j = i + 1;
            while j < c.len() && c[j] != '"' {
                j += if c[j] == '\\' { 2 } else { 1 };
            }
            let text: String = c[i + 1..j.min(c.len())].iter().collect();
            j = (j + 1).min(c.len());
            count(i, j, &mut line);
            out.push(Token { tok: Tok::Str(text), line: start_line });
            i = j;
        } else if ch == '\'' {
            if at(i + 1) == '\\' {
                let mut j = i + 2;
                while j < c.len() && c[j] != '\'' && c[j] != '\n' {
                    j += if c[j] == '\\' { 2 } else { 1 };
                }
                i = (j + 1).min(c.len());
            } else if at(i + 2) == '\'' {
                i += 3;
            } else {
                // A lifetime or label.
                let mut j = i + 1;
                while j < c.len() && is_ident_continue(c[j]) {
                    j += 1;
                }
                i = j.max(i + 1);
            }
            out.push(Token { tok: Tok::Lit, line });
        } else if ch.is_ascii_digit() {
            let mut j = i;
            while j < c.len() && (is_ident_continue(c[j]) || (c[j] == '.' && at(j + 1).is_ascii_digit())) {
                j += 1;
            }
            out.push(Token { tok: Tok::Lit, line });
            i = j;
        } else if ch == ':' && at(i + 1) == ':' {
            out.push(Token { tok: Tok::PathSep, line });
            i += 2;
        } else {
            out.push(Token { tok: Tok::Punct(ch), line });
            i += 1;
        }
    }
    out
}

/// One `mod` declaration of a file.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ModDecl {
    /// The module's name.
    pub name: String,
    /// The inline modules of the file it is declared in (empty: the file's own module).
    pub scope: Vec<String>,
    /// Declared with a `{ … }` body in this file.
    pub inline: bool,
    /// A test module (named `tests`, inline or not): not part of the layering.
    pub test: bool,
    /// An inline module inside a function or macro body (or a macro's `mod $name { … }`):
    /// not part of the layering or of the groups, only of `super` resolution.
    pub nested: bool,
    /// The value of a `#[path = "…"]` attribute.
    pub path_attr: Option<String>,
    /// Its group (layer) among the declarations of its scope, from 0 (the lowest).
    pub group: usize,
    /// The line of the `mod` keyword.
    pub line: usize,
    /// The first line of the declaration: its doc comments, attributes and visibility.
    pub start_line: usize,
    /// Its last line (the `;`, or an inline module's closing brace).
    pub end_line: usize,
}

/// A path beginning with `crate`, `super` or `self` found in code.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Import {
    /// The inline modules of the file it occurs in (empty: the file's own module).
    pub scope: Vec<String>,
    /// Its segments, the first being `crate`, `super` or `self` (a glob ends before the `*`).
    pub path: Vec<String>,
    /// The line of its last segment.
    pub line: usize,
}

/// What the checker reads from one file.
#[derive(Clone, Debug, Default)]
pub struct FileInfo {
    /// Its `mod` declarations in source order, groups assigned.
    pub mods: Vec<ModDecl>,
    /// Its `crate::` / `super::` / `self::` paths in source order.
    pub imports: Vec<Import>,
}

fn ident(tokens: &[Token], i: usize) -> Option<&str> {
    match tokens.get(i).map(|t| &t.tok) {
        Some(Tok::Ident(s)) => Some(s),
        _ => None,
    }
}

fn is(tokens: &[Token], i: usize, tok: &Tok) -> bool {
    tokens.get(i).is_some_and(|t| &t.tok == tok)
}

fn is_root_keyword(s: &str) -> bool {
    matches!(s, "crate" | "super" | "self")
}

/// Parses a use tree at `tokens[*i]` with the segments `prefix` above it, pushing every leaf path.
fn use_tree(tokens: &[Token], i: &mut usize, prefix: &[String], out: &mut Vec<(Vec<String>, usize)>) {
    let mut segs = prefix.to_vec();
    if is(tokens, *i, &Tok::PathSep) {
        *i += 1; // a leading `::`: an external crate
        segs.push("::".to_string());
    }
    while let Some(t) = tokens.get(*i) {
        match &t.tok {
            Tok::Ident(name) => {
                segs.push(name.clone());
                *i += 1;
                if is(tokens, *i, &Tok::PathSep) {
                    *i += 1;
                    continue;
                }
                if ident(tokens, *i) == Some("as") {
                    *i += 2;
                }
                out.push((segs, t.line));
                return;
            }
            Tok::Punct('*') => {
                *i += 1;
                out.push((segs, t.line));
                return;
            }
            Tok::Punct('{') => {
                *i += 1;
                while *i < tokens.len() {
                    if is(tokens, *i, &Tok::Punct('}')) {
                        *i += 1;
                        break;
                    }
                    let before = *i;
                    use_tree(tokens, i, &segs, out);
                    if is(tokens, *i, &Tok::Punct(',')) {
                        *i += 1;
                    } else if *i == before {
                        *i += 1; // not a use tree: do not loop forever
                    }
                }
                return;
            }
            _ => return,
        }
    }
}

/// The index of the token matching the closer at `close` (`)` or `]`), searching backwards.
fn open_of(tokens: &[Token], close: usize) -> Option<usize> {
    let (open, shut) = match tokens[close].tok {
        Tok::Punct(')') => ('(', ')'),
        Tok::Punct(']') => ('[', ']'),
        _ => return None,
    };
    let mut depth = 0;
    for j in (0..=close).rev() {
        if tokens[j].tok == Tok::Punct(shut) {
            depth += 1;
        } else if tokens[j].tok == Tok::Punct(open) {
            depth -= 1;
            if depth == 0 {
                return Some(j);
            }
        }
    }
    None
}

/// The name of the module declared by the `mod` at `tokens[i]` and the index of its `;` or `{`:
/// `mod name;`, `mod name {`, and (`nested`: inside a function or macro body) only the inline
/// forms `mod name {` and `mod $name {` (a macro's module, named `$name`).
fn mod_header(tokens: &[Token], i: usize, nested: bool) -> Option<(String, usize)> {
    let (name, k) = match ident(tokens, i + 1) {
        Some(name) => (name.to_string(), i + 2),
        None if is(tokens, i + 1, &Tok::Punct('$')) => (format!("${}", ident(tokens, i + 2)?), i + 3),
        None => return None,
    };
    let inline = is(tokens, k, &Tok::Punct('{'));
    let plain = !nested && !name.starts_with('$');
    (inline || (plain && is(tokens, k, &Tok::Punct(';')))).then_some((name, k))
}

/// Reads a file's `mod` declarations (with their groups) and its `crate::` / `super::` /
/// `self::` paths.
pub fn parse_file(src: &str) -> FileInfo {
    let tokens = lex(src);
    let lines: Vec<&str> = src.lines().collect();
    let mut info = FileInfo::default();
    // Open inline modules: (index in info.mods, brace depth of its body).
    let mut stack: Vec<(usize, usize)> = Vec::new();
    let mut depth = 0usize;
    let scope = |stack: &[(usize, usize)], mods: &[ModDecl]| -> Vec<String> {
        stack.iter().map(|&(m, _)| mods[m].name.clone()).collect()
    };
    let mut i = 0;
    while i < tokens.len() {
        let line = tokens[i].line;
        match &tokens[i].tok {
            Tok::Punct('{') => depth += 1,
            Tok::Punct('}') => {
                depth = depth.saturating_sub(1);
                if let Some(&(m, body)) = stack.last()
                    && depth < body
                {
                    info.mods[m].end_line = line;
                    stack.pop();
                }
            }
            Tok::Ident(kw)
                if kw == "mod" && mod_header(&tokens, i, depth != stack.last().map_or(0, |s| s.1)).is_some() =>
            {
                let nested = depth != stack.last().map_or(0, |s| s.1);
                let (name, k) = mod_header(&tokens, i, nested).unwrap_or_default();
                let nested = nested || name.starts_with('$');
                // Walk back over the visibility and outer attributes.
                let mut j = i;
                loop {
                    if j > 0 && ident(&tokens, j - 1) == Some("pub") {
                        j -= 1;
                    } else if j > 1
                        && tokens[j - 1].tok == Tok::Punct(')')
                        && let Some(o) = open_of(&tokens, j - 1)
                        && o > 0
                        && ident(&tokens, o - 1) == Some("pub")
                    {
                        j = o - 1;
                    } else if j > 1
                        && tokens[j - 1].tok == Tok::Punct(']')
                        && let Some(o) = open_of(&tokens, j - 1)
                        && o > 0
                        && tokens[o - 1].tok == Tok::Punct('#')
                    {
                        j = o - 1;
                    } else {
                        break;
                    }
                }
                let attrs = &tokens[j..i];
                let path_attr = attrs.windows(3).find_map(|w| match (&w[0].tok, &w[1].tok, &w[2].tok) {
                    (Tok::Ident(p), Tok::Punct('='), Tok::Str(s)) if p == "path" => Some(s.clone()),
                    _ => None,
                });
                let mut start_line = tokens[j].line;
                while start_line >= 2 {
                    let above = lines.get(start_line - 2).map_or("", |l| l.trim_start());
                    if above.starts_with("///") && !above.starts_with("////") {
                        start_line -= 1;
                    } else {
                        break;
                    }
                }
                let inline = is(&tokens, k, &Tok::Punct('{'));
                info.mods.push(ModDecl {
                    test: name == "tests",
                    nested,
                    scope: scope(&stack, &info.mods),
                    name,
                    inline,
                    path_attr,
                    group: 0,
                    line,
                    start_line,
                    end_line: tokens[k].line,
                });
                if inline {
                    depth += 1;
                    stack.push((info.mods.len() - 1, depth));
                }
                i = k + 1;
                continue;
            }
            Tok::Ident(kw) if kw == "use" => {
                let mut paths = Vec::new();
                i += 1;
                use_tree(&tokens, &mut i, &[], &mut paths);
                let sc = scope(&stack, &info.mods);
                for (path, line) in paths {
                    if path.first().is_some_and(|s| is_root_keyword(s)) {
                        info.imports.push(Import { scope: sc.clone(), path, line });
                    }
                }
                continue;
            }
            Tok::Ident(kw) if is_root_keyword(kw) && is(&tokens, i + 1, &Tok::PathSep) => {
                let after_sep = i > 0 && tokens[i - 1].tok == Tok::PathSep;
                let visibility = i > 1 && ident(&tokens, i - 1) == Some("in") && tokens[i - 2].tok == Tok::Punct('(');
                let mut path = vec![kw.clone()];
                let mut j = i + 1;
                let mut last = line;
                while is(&tokens, j, &Tok::PathSep)
                    && let Some(seg) = ident(&tokens, j + 1)
                {
                    path.push(seg.to_string());
                    last = tokens[j + 1].line;
                    j += 2;
                }
                if !after_sep && !visibility {
                    info.imports.push(Import { scope: scope(&stack, &info.mods), path, line: last });
                }
                i = j;
                continue;
            }
            _ => {}
        }
        i += 1;
    }
    assign_groups(&mut info.mods);
    info
}

/// Numbers the groups of each scope's declarations: a declaration starting on the line after
/// the previous one's end stays in its group, anything else between them starts the next.
fn assign_groups(mods: &mut [ModDecl]) {
    let mut last: HashMap<Vec<String>, (usize, usize)> = HashMap::new(); // scope → (end line, group)
    for m in mods.iter_mut().filter(|m| !m.nested) {
        let group = match last.get(&m.scope) {
            None => 0,
            Some(&(end, g)) if m.start_line == end + 1 => g,
            Some(&(_, g)) => g + 1,
        };
        m.group = group;
        last.insert(m.scope.clone(), (m.end_line, group));
    }
}

/// A module of a tree.
#[derive(Clone, Debug)]
pub struct Module {
    /// Its path from the crate root (empty for the root).
    pub path: Vec<String>,
    /// The index of the file it lives in.
    pub file: usize,
    /// Its parent module.
    pub parent: Option<usize>,
    /// Its submodules by name.
    pub children: BTreeMap<String, usize>,
    /// Its group among its parent's declarations.
    pub group: usize,
    /// Not layered: a test module, a module nested in a function or macro body, or inside one.
    pub test: bool,
}

/// An import site of a tree.
#[derive(Clone, Debug)]
pub struct Site {
    /// The module it occurs in.
    pub module: usize,
    /// The file it occurs in.
    pub file: usize,
    /// The path as written (segments).
    pub path: Vec<String>,
    /// Its line.
    pub line: usize,
}

/// One crate root's module tree and import sites.
#[derive(Clone, Debug, Default)]
pub struct Tree {
    /// Its files; the root file first.
    pub files: Vec<PathBuf>,
    /// Its modules; the crate root first.
    pub modules: Vec<Module>,
    /// Every `crate::` / `super::` / `self::` path.
    pub sites: Vec<Site>,
    /// Declarations whose file was not found, and files that could not be read.
    pub notes: Vec<String>,
}

/// Builds the module tree from `root_file` (a `lib.rs` or `main.rs`), reading files with `read`.
pub fn build_tree(root_file: &Path, read: &dyn Fn(&Path) -> Option<String>) -> Tree {
    let mut tree = Tree::default();
    tree.modules.push(Module {
        path: Vec::new(),
        file: 0,
        parent: None,
        children: BTreeMap::new(),
        group: 0,
        test: false,
    });
    // (file, its module, whether nested declarations look in the file's own folder)
    let mut queue = VecDeque::from([(root_file.to_path_buf(), 0usize, true)]);
    let mut seen = BTreeSet::new();
    while let Some((file, module, mod_rs)) = queue.pop_front() {
        if !seen.insert(file.clone()) {
            continue;
        }
        let Some(src) = read(&file) else {
            tree.notes.push(format!("{}: cannot read", file.display()));
            continue;
        };
        let fi = tree.files.len();
        tree.files.push(file.clone());
        tree.modules[module].file = fi;
        let info = parse_file(&src);
        let dir = file.parent().unwrap_or(Path::new("")).to_path_buf();
        let base = if mod_rs { dir.clone() } else { dir.join(file.file_stem().unwrap_or_default()) };
        let mut scopes: HashMap<Vec<String>, usize> = HashMap::from([(Vec::new(), module)]);
        for decl in &info.mods {
            let Some(&parent) = scopes.get(&decl.scope) else { continue };
            let mut path = tree.modules[parent].path.clone();
            path.push(decl.name.clone());
            let child = tree.modules.len();
            tree.modules.push(Module {
                path,
                file: fi,
                parent: Some(parent),
                children: BTreeMap::new(),
                group: decl.group,
                test: decl.test || decl.nested || tree.modules[parent].test,
            });
            tree.modules[parent].children.insert(decl.name.clone(), child);
            if decl.inline {
                let mut s = decl.scope.clone();
                s.push(decl.name.clone());
                scopes.insert(s, child);
                continue;
            }
            let candidates = if let Some(p) = &decl.path_attr {
                let inner = decl.scope.iter().fold(dir.clone(), |d, s| d.join(s));
                vec![(inner.join(p), true)]
            } else {
                let inner = decl.scope.iter().fold(base.clone(), |d, s| d.join(s));
                vec![(inner.join(format!("{}.rs", decl.name)), false), (inner.join(&decl.name).join("mod.rs"), true)]
            };
            match candidates.iter().find(|(p, _)| read(p).is_some()) {
                Some((p, rs)) => queue.push_back((p.clone(), child, *rs)),
                None => tree.notes.push(format!(
                    "{}:{}: no file for `mod {}` ({})",
                    file.display(),
                    decl.line,
                    decl.name,
                    candidates.iter().map(|(p, _)| p.display().to_string()).collect::<Vec<_>>().join(" or ")
                )),
            }
        }
        for imp in info.imports {
            if let Some(&m) = scopes.get(&imp.scope) {
                tree.sites.push(Site { module: m, file: fi, path: imp.path, line: imp.line });
            }
        }
    }
    tree
}

/// The deepest module `path` names, seen from module `site`; `None` when `super` climbs above
/// the root.
pub fn resolve(tree: &Tree, site: usize, path: &[String]) -> Option<usize> {
    let (first, rest) = path.split_first()?;
    let mut cur = match first.as_str() {
        "crate" => 0,
        "self" => site,
        "super" => tree.modules[site].parent?,
        _ => return None,
    };
    for seg in rest {
        match seg.as_str() {
            "self" => {}
            "super" => cur = tree.modules[cur].parent?,
            name => match tree.modules[cur].children.get(name) {
                Some(&c) => cur = c,
                None => break,
            },
        }
    }
    Some(cur)
}

/// The module's name as a path (`crate::a::b`).
pub fn module_name(tree: &Tree, m: usize) -> String {
    std::iter::once("crate".to_string()).chain(tree.modules[m].path.iter().cloned()).collect::<Vec<_>>().join("::")
}

/// The nearest module that is not a test module, starting at `m`.
fn layered(tree: &Tree, mut m: usize) -> usize {
    while tree.modules[m].test
        && let Some(p) = tree.modules[m].parent
    {
        m = p;
    }
    m
}

/// The chain of modules from the root down to `m`.
fn chain(tree: &Tree, mut m: usize) -> Vec<usize> {
    let mut out = vec![m];
    while let Some(p) = tree.modules[m].parent {
        out.push(p);
        m = p;
    }
    out.reverse();
    out
}

/// A violation of the layering rules.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Violation {
    /// The file it is reported in.
    pub file: PathBuf,
    /// The line.
    pub line: usize,
    /// What is wrong.
    pub message: String,
}

/// The result of checking one tree.
#[derive(Clone, Debug, Default)]
pub struct Check {
    /// Files taking part in the layering (test-module files count as their declaring file's).
    pub files: usize,
    /// Import edges between distinct files: (from, to) → (file, line) of the first import.
    pub edges: BTreeMap<(usize, usize), (usize, usize)>,
    /// Files by level (level 0: imports nothing of its crate).
    pub levels: Vec<Vec<usize>>,
    /// The violations, upward imports first, then circles.
    pub violations: Vec<Violation>,
}

/// Checks a tree: the ancestor and group rules on each import, then circles between files.
pub fn check(tree: &Tree) -> Check {
    let mut out = Check::default();
    let mut reported = BTreeSet::new();
    for site in &tree.sites {
        let Some(target) = resolve(tree, site.module, &site.path) else { continue };
        let (m, n) = (layered(tree, site.module), layered(tree, target));
        let (from, to) = (tree.modules[m].file, tree.modules[n].file);
        if from == to {
            continue;
        }
        out.edges.entry((from, to)).or_insert((site.file, site.line));
        let (cm, cn) = (chain(tree, m), chain(tree, n));
        let k = cm.iter().zip(&cn).take_while(|(a, b)| a == b).count();
        let p = cm[k - 1];
        let message = if n == p {
            format!(
                "`{}` imports its ancestor `{}`'s file (`{}`): parents declare and re-export, children do not reach back up",
                module_name(tree, m),
                module_name(tree, p),
                site.path.join("::")
            )
        } else if m == p {
            continue;
        } else {
            let (a, b) = (&tree.modules[cm[k]], &tree.modules[cn[k]]);
            if b.group <= a.group {
                continue;
            }
            format!(
                "`{}` imports `{}`, declared in a higher layer of `{}`'s file (group {} > {})",
                module_name(tree, m),
                module_name(tree, n),
                module_name(tree, p),
                b.group + 1,
                a.group + 1
            )
        };
        if reported.insert((from, n)) {
            out.violations.push(Violation { file: tree.files[site.file].clone(), line: site.line, message });
        }
    }
    let nodes: BTreeSet<usize> = tree.modules.iter().filter(|m| !m.test).map(|m| m.file).collect();
    out.files = nodes.len();
    let mut succ: BTreeMap<usize, Vec<usize>> = nodes.iter().map(|&f| (f, Vec::new())).collect();
    for &(a, b) in out.edges.keys() {
        succ.entry(a).or_default().push(b);
        succ.entry(b).or_default();
    }
    let sccs = strongly_connected(&succ);
    // Levels: Tarjan emits components sinks first, so successors are done before each one.
    let mut comp_of = BTreeMap::new();
    for (ci, comp) in sccs.iter().enumerate() {
        for &f in comp {
            comp_of.insert(f, ci);
        }
    }
    let mut level = vec![0usize; sccs.len()];
    for (ci, comp) in sccs.iter().enumerate() {
        level[ci] = comp
            .iter()
            .flat_map(|f| &succ[f])
            .map(|t| comp_of[t])
            .filter(|&cj| cj != ci)
            .map(|cj| level[cj] + 1)
            .max()
            .unwrap_or(0);
        let l = level[ci];
        if out.levels.len() <= l {
            out.levels.resize(l + 1, Vec::new());
        }
        out.levels[l].extend(comp.iter().copied());
    }
    for files in &mut out.levels {
        files.sort_by(|a, b| tree.files[*a].cmp(&tree.files[*b]));
    }
    for comp in sccs.iter().filter(|c| c.len() > 1) {
        let cycle = shortest_cycle(comp, &succ, tree);
        let steps: Vec<String> = cycle
            .windows(2)
            .map(|w| {
                let (f, line) = out.edges[&(w[0], w[1])];
                if f == w[0] {
                    format!("{}:{line}", short(tree, f))
                } else {
                    format!("{} ({}:{line})", short(tree, w[0]), short(tree, f))
                }
            })
            .chain(std::iter::once(short(tree, cycle[0])))
            .collect();
        let (f, line) = out.edges[&(cycle[0], cycle[1])];
        let extra = if comp.len() + 1 > cycle.len() {
            format!(" (a circle of {} files in all)", comp.len())
        } else {
            String::new()
        };
        out.violations.push(Violation {
            file: tree.files[f].clone(),
            line,
            message: format!("import circle: {}{extra}", steps.join(" → ")),
        });
    }
    out
}

/// A file's path below its crate's `src/` (or its whole path when it is not under one).
fn short(tree: &Tree, f: usize) -> String {
    let root_dir = tree.files[0].parent().unwrap_or(Path::new(""));
    tree.files[f].strip_prefix(root_dir).unwrap_or(&tree.files[f]).display().to_string()
}

/// Tarjan's strongly connected components, sinks first.
pub fn strongly_connected(succ: &BTreeMap<usize, Vec<usize>>) -> Vec<Vec<usize>> {
    struct State<'a> {
        succ: &'a BTreeMap<usize, Vec<usize>>,
        index: BTreeMap<usize, usize>,
        low: BTreeMap<usize, usize>,
        on_stack: BTreeSet<usize>,
        stack: Vec<usize>,
        out: Vec<Vec<usize>>,
    }
    fn visit(s: &mut State, v: usize) {
        let i = s.index.len();
        s.index.insert(v, i);
        s.low.insert(v, i);
        s.stack.push(v);
        s.on_stack.insert(v);
        for &w in s.succ.get(&v).map_or(&[][..], |x| x) {
            if !s.index.contains_key(&w) {
                visit(s, w);
                let lw = s.low[&w];
                let lv = s.low.get_mut(&v).expect("visited");
                *lv = (*lv).min(lw);
            } else if s.on_stack.contains(&w) {
                let iw = s.index[&w];
                let lv = s.low.get_mut(&v).expect("visited");
                *lv = (*lv).min(iw);
            }
        }
        if s.low[&v] == s.index[&v] {
            let mut comp = Vec::new();
            while let Some(w) = s.stack.pop() {
                s.on_stack.remove(&w);
                comp.push(w);
                if w == v {
                    break;
                }
            }
            comp.sort_unstable();
            s.out.push(comp);
        }
    }
    let mut s = State {
        succ,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        on_stack: BTreeSet::new(),
        stack: Vec::new(),
        out: Vec::new(),
    };
    for &v in succ.keys() {
        if !s.index.contains_key(&v) {
            visit(&mut s, v);
        }
    }
    s.out
}

/// A shortest cycle through the component's first file (by path): `[a, b, …, a]`.
fn shortest_cycle(comp: &[usize], succ: &BTreeMap<usize, Vec<usize>>, tree: &Tree) -> Vec<usize> {
    let inside: BTreeSet<usize> = comp.iter().copied().collect();
    let start = *comp.iter().min_by(|a, b| tree.files[**a].cmp(&tree.files[**b])).expect("non-empty");
    let mut prev: BTreeMap<usize, usize> = BTreeMap::new();
    let mut queue = VecDeque::from([start]);
    while let Some(v) = queue.pop_front() {
        for &w in &succ[&v] {
            if !inside.contains(&w) {
                continue;
            }
            if w == start {
                let mut path = vec![start, v];
                let mut cur = v;
                while cur != start {
                    cur = prev[&cur];
                    path.push(cur);
                }
                path.reverse();
                return path;
            }
            if let std::collections::btree_map::Entry::Vacant(e) = prev.entry(w) {
                e.insert(v);
                queue.push_back(w);
            }
        }
    }
    unreachable!("a strongly connected component of two or more files has a cycle through each file")
}

/// The source trees of the workspace at `root`: (display name, root file), `crates/*` then `xtask`.
pub fn crate_roots(root: &Path) -> Vec<(String, PathBuf)> {
    let mut packages: Vec<PathBuf> = std::fs::read_dir(root.join("crates"))
        .map(|d| d.filter_map(|e| e.ok().map(|e| e.path())).filter(|p| p.join("src").is_dir()).collect())
        .unwrap_or_default();
    packages.sort();
    packages.push(root.join("xtask"));
    let mut out = Vec::new();
    for pkg in packages {
        let name = pkg.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let files: Vec<PathBuf> =
            ["lib.rs", "main.rs"].iter().map(|f| pkg.join("src").join(f)).filter(|p| p.is_file()).collect();
        let both = files.len() == 2;
        for f in files {
            let label = if both {
                format!("{name} ({})", f.file_name().unwrap_or_default().to_string_lossy())
            } else {
                name.clone()
            };
            out.push((label, f));
        }
    }
    out
}

/// Checks every source tree under `root` and renders the report; returns it with the number of
/// violations.
pub fn report(root: &Path, verbose: bool) -> (String, usize) {
    let read = |p: &Path| std::fs::read_to_string(p).ok();
    let rel = |p: &Path| p.strip_prefix(root).unwrap_or(p).display().to_string();
    let mut text = String::new();
    let mut total = 0;
    for (name, root_file) in crate_roots(root) {
        let tree = build_tree(&root_file, &read);
        let result = check(&tree);
        let _ = writeln!(
            text,
            "{name}: {} files, {} import edges, {} levels, {} violations",
            result.files,
            result.edges.len(),
            result.levels.len(),
            result.violations.len()
        );
        if verbose {
            for (l, files) in result.levels.iter().enumerate() {
                let names: Vec<String> = files.iter().map(|&f| short(&tree, f)).collect();
                let _ = writeln!(text, "  level {l}: {}", names.join(", "));
            }
        }
        for note in &tree.notes {
            let _ = writeln!(text, "  note: {}", note.replace(&format!("{}/", root.display()), ""));
        }
        for v in &result.violations {
            let _ = writeln!(text, "{}:{}: {}", rel(&v.file), v.line, v.message);
        }
        total += result.violations.len();
    }
    (text, total)
}

/// `cargo xtask layers [--root DIR] [--verbose]`: prints the report and fails on any violation.
pub fn run(root: &Path, verbose: bool) -> Result<(), String> {
    let (text, violations) = report(root, verbose);
    print!("{text}");
    if violations == 0 {
        println!("layers: no upward imports, no import circles");
        Ok(())
    } else {
        Err(format!("layers: {violations} violations"))
    }
}
