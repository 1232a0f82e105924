//! `cargo xtask layers`' checker, compiled into a test harness from its source (the xtask
//! binary links the whole project; these tests need none of it).

#[path = "../src/layers.rs"]
mod layers;

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use layers::{Tree, build_tree, check, parse_file, resolve};

/// The (name, group) of each layered declaration of `src`'s top scope.
fn groups(src: &str) -> Vec<(String, usize)> {
    parse_file(src).mods.into_iter().filter(|m| m.scope.is_empty() && !m.test).map(|m| (m.name, m.group)).collect()
}

fn owned(v: &[(&str, usize)]) -> Vec<(String, usize)> {
    v.iter().map(|(n, g)| (n.to_string(), *g)).collect()
}

/// The import paths of `src`, as `a::b::c` strings.
fn imports(src: &str) -> Vec<String> {
    parse_file(src).imports.into_iter().map(|i| i.path.join("::")).collect()
}

/// A tree from in-memory files (paths under `src/`).
fn tree(files: &[(&str, &str)]) -> Tree {
    let map: HashMap<PathBuf, String> = files.iter().map(|(p, s)| (Path::new("src").join(p), s.to_string())).collect();
    build_tree(Path::new("src/lib.rs"), &|p: &Path| map.get(p).cloned())
}

/// The violation messages of a tree, as `file:line: message`.
fn violations(files: &[(&str, &str)]) -> Vec<String> {
    check(&tree(files))
        .violations
        .into_iter()
        .map(|v| format!("{}:{}: {}", v.file.display(), v.line, v.message))
        .collect()
}

#[test]
fn mod_groups_split_at_blank_and_comment_lines() {
    let src = "//! Crate doc mentioning mod fake;\n\
               \n\
               mod a;\n\
               pub mod b;\n\
               \n\
               // Middle layer.\n\
               pub(crate) mod c;\n\
               /// Doc of d.\n\
               #[cfg(feature = \"train\")]\n\
               pub(in crate::x) mod d;\n\
               // Top.\n\
               mod e;\n\
               use e::Thing;\n\
               mod f;\n\
               \n\
               #[cfg(test)]\n\
               mod tests {\n\
               \x20   mod inner;\n\
               \x20   use super::*;\n\
               }\n";
    assert_eq!(groups(src), owned(&[("a", 0), ("b", 0), ("c", 1), ("d", 1), ("e", 2), ("f", 3)]));
    let info = parse_file(src);
    let tests = info.mods.iter().find(|m| m.name == "tests").expect("tests declared");
    assert!(tests.test && tests.inline);
    let inner = info.mods.iter().find(|m| m.name == "inner").expect("nested declaration");
    assert_eq!(inner.scope, vec!["tests".to_string()]);
}

#[test]
fn attributes_between_declarations_keep_the_group() {
    let src =
        "mod a;\n#[cfg(feature = \"x\")]\n#[allow(dead_code)]\nmod b;\n#[cfg(test)]\nmod tests;\nmod c;\n\nmod d;\n";
    assert_eq!(groups(src), owned(&[("a", 0), ("b", 0), ("c", 0), ("d", 1)]));
    // A `#[cfg(test)]` helper with another name is layered like any module.
    let src = "#[cfg(test)]\nmod helpers;\n\nmod a;\n";
    assert_eq!(groups(src), owned(&[("helpers", 0), ("a", 1)]));
}

#[test]
fn use_trees_are_expanded() {
    let src = "use crate::{a::{b, c as d}, e::*};\n\
               pub use super::f::{self, G};\n\
               pub(crate) use self::h::I as J;\n\
               use std::fmt;\n\
               use ::other::crate_thing;\n\
               use {crate::k, super::super::l::M};\n";
    assert_eq!(
        imports(src),
        [
            "crate::a::b",
            "crate::a::c",
            "crate::e",
            "super::f::self",
            "super::f::G",
            "self::h::I",
            "crate::k",
            "super::super::l::M"
        ]
    );
}

#[test]
fn comments_strings_and_visibilities_are_not_imports() {
    let src = r####"
// use crate::commented;
/// Docs: `crate::doc::path` and use crate::doc_use;
/* block /* nested crate::x */ use crate::y; */
fn f<'a>(s: &'a str) -> char {
    let _ = "use crate::in_string; \" crate::still_string";
    let _ = r#"crate::raw "quoted" crate::raw2"#;
    let _ = br##"crate::raw_bytes"##;
    let _ = b"crate::bytes";
    let c = '"';
    let _ = '\'';
    pub(in crate::vis) struct S;
    crate::real::call(s, c)
}
"####;
    assert_eq!(imports(src), ["crate::real::call"]);
}

#[test]
fn inline_paths_are_imports() {
    let src = "fn f() -> crate::a::B { let x: super::c::D = crate::e::f::<u8>(1); self::g::h(); $crate::m::n!(); x.into() }\n";
    assert_eq!(imports(src), ["crate::a::B", "super::c::D", "crate::e::f", "self::g::h", "crate::m::n"]);
    // Line numbers: the line of a path's last segment.
    let info = parse_file("\n\nuse crate::{\n    a,\n    b::C,\n};\n");
    assert_eq!(info.imports.iter().map(|i| i.line).collect::<Vec<_>>(), [4, 5]);
}

#[test]
fn paths_resolve_to_the_deepest_module() {
    let t = tree(&[
        ("lib.rs", "mod a;\nmod b;\n"),
        ("a.rs", "pub mod inner { pub mod deep { pub fn f() {} } }\n"),
        ("b/mod.rs", "mod c;\n"),
        ("b/c.rs", "mod tests {\n    use super::super::X;\n}\n"),
    ]);
    let name = |m: usize| layers::module_name(&t, m);
    let path = |s: &str| s.split("::").map(String::from).collect::<Vec<_>>();
    let c = (0..t.modules.len()).find(|&m| name(m) == "crate::b::c").expect("module c");
    assert_eq!(name(resolve(&t, c, &path("crate::a::inner::deep::f")).unwrap()), "crate::a::inner::deep");
    assert_eq!(name(resolve(&t, c, &path("crate::a::Item::method")).unwrap()), "crate::a");
    assert_eq!(name(resolve(&t, c, &path("super::Thing")).unwrap()), "crate::b");
    assert_eq!(name(resolve(&t, c, &path("self::x")).unwrap()), "crate::b::c");
    assert_eq!(name(resolve(&t, c, &path("crate::a::self::inner")).unwrap()), "crate::a::inner");
    // `super` inside the inline `tests` module: its enclosing module `c`, then `b`.
    let tests = (0..t.modules.len()).find(|&m| name(m) == "crate::b::c::tests").expect("inline tests");
    assert_eq!(name(resolve(&t, tests, &path("super::super::X")).unwrap()), "crate::b");
    assert_eq!(t.files.len(), 4);
    assert!(t.notes.is_empty(), "{:?}", t.notes);
}

#[test]
fn importing_an_ancestors_file_is_a_violation() {
    let v = violations(&[
        ("lib.rs", "mod error;\n\nmod a;\npub use error::Error;\n"),
        ("error.rs", "pub struct Error;\n"),
        ("a/mod.rs", "mod b;\n"),
        ("a/b.rs", "use crate::Error;\nuse super::helper;\n"),
    ]);
    assert_eq!(
        v,
        [
            "src/a/b.rs:1: `crate::a::b` imports its ancestor `crate`'s file (`crate::Error`): parents declare and re-export, children do not reach back up",
            "src/a/b.rs:2: `crate::a::b` imports its ancestor `crate::a`'s file (`super::helper`): parents declare and re-export, children do not reach back up",
        ]
    );
    // A parent importing its descendants is fine, and so is a child's inline `tests` module
    // importing its own file.
    let v = violations(&[
        ("lib.rs", "mod a;\nuse crate::a::b::f;\n"),
        ("a.rs", "pub mod b;\nfn g() { self::b::f() }\n#[cfg(test)]\nmod tests {\n    use super::*;\n}\n"),
        ("a/b.rs", "pub fn f() {}\n"),
    ]);
    assert!(v.is_empty(), "{v:?}");
}

#[test]
fn modules_in_function_and_macro_bodies_only_steer_super() {
    let a = "pub struct U;\n\
             mod simd {\n\
             \x20   macro_rules! variant {\n\
             \x20       ($m:ident) => {\n\
             \x20           pub(super) mod $m {\n\
             \x20               use super::super::U;\n\
             \x20           }\n\
             \x20       };\n\
             \x20   }\n\
             }\n\
             fn f() {\n\
             \x20   mod local {\n\
             \x20       use super::U;\n\
             \x20   }\n\
             }\n\
             mod b;\n";
    let info = parse_file(a);
    let decls: Vec<_> = info.mods.iter().map(|m| (m.name.as_str(), m.scope.join("::"), m.nested, m.group)).collect();
    assert_eq!(
        decls,
        [
            ("simd", String::new(), false, 0),
            ("$m", "simd".into(), true, 0),
            ("local", String::new(), true, 0),
            ("b", String::new(), false, 1)
        ]
    );
    // Without the macro's module, `super::super` would reach `crate`'s file from `a::simd`.
    let v = violations(&[("lib.rs", "mod a;\n"), ("a.rs", a), ("a/b.rs", "")]);
    assert!(v.is_empty(), "{v:?}");
}

#[test]
fn importing_a_higher_group_is_a_violation() {
    let files = [
        ("lib.rs", "mod low;\nmod low2;\n\n// Middle.\nmod mid;\n\nmod high;\n"),
        ("low.rs", "use crate::low2::X;\n"),
        ("low2.rs", "pub struct X;\n"),
        ("mid.rs", "use crate::low::Y;\nuse crate::high::nested::Z;\n"),
        ("high.rs", "pub mod nested;\nuse crate::mid::W;\n"),
        ("high/nested.rs", "use crate::low::Q;\n"),
    ];
    assert_eq!(
        violations(&files),
        [
            "src/mid.rs:2: `crate::mid` imports `crate::high::nested`, declared in a higher layer of `crate`'s file (group 3 > 2)"
        ]
    );
}

#[test]
fn two_and_three_file_circles_are_violations() {
    let two = [("lib.rs", "mod a;\nmod b;\n"), ("a.rs", "use crate::b::X;\n"), ("b.rs", "\nuse super::a::Y;\n")];
    assert_eq!(violations(&two), ["src/a.rs:1: import circle: a.rs:1 → b.rs:2 → a.rs"]);
    let three = [
        ("lib.rs", "mod x;\n"),
        ("x/mod.rs", "mod a;\nmod b;\nmod c;\n"),
        ("x/a.rs", "fn f() { super::b::g() }\n"),
        ("x/b.rs", "\n\nuse super::c;\n"),
        ("x/c.rs", "\nuse crate::x::a::T;\n"),
    ];
    assert_eq!(violations(&three), ["src/x/a.rs:1: import circle: x/a.rs:1 → x/b.rs:3 → x/c.rs:2 → x/a.rs"]);
}

#[test]
fn clean_tree_passes_on_disk() {
    let root = std::env::temp_dir().join(format!("w3d-layers-test-{}", std::process::id()));
    let write = |p: &str, s: &str| {
        let path = root.join(p);
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(path, s).unwrap();
    };
    let _ = std::fs::remove_dir_all(&root);
    write("crates/demo/src/lib.rs", "//! Demo.\nmod base;\n\nmod ops;\npub mod io;\n\nmod top;\npub use top::run;\n");
    write("crates/demo/src/base.rs", "pub struct Mesh;\n#[cfg(test)]\nmod tests {\n    use super::*;\n}\n");
    write("crates/demo/src/ops.rs", "use crate::base::Mesh;\npub fn op(_: &Mesh) {}\n");
    // `obj::read`: a path without `crate::` / `super::` / `self::` is not an import.
    write("crates/demo/src/io/mod.rs", "mod obj;\npub use obj::read;\n");
    write("crates/demo/src/io/obj.rs", "pub fn read() -> crate::base::Mesh { crate::base::Mesh }\n");
    write("crates/demo/src/top.rs", "use crate::{io, ops::op};\npub fn run() { op(&io::read()) }\n");
    write("xtask/src/main.rs", "//! Tasks.\nfn main() {}\n");
    let (text, n) = layers::report(&root, true);
    assert_eq!(n, 0, "{text}");
    assert!(text.starts_with("demo: 6 files, 4 import edges, 3 levels, 0 violations\n"), "{text}");
    assert!(
        text.contains("  level 0: base.rs, io/mod.rs, lib.rs\n  level 1: io/obj.rs, ops.rs\n  level 2: top.rs\n"),
        "{text}"
    );
    assert!(layers::run(&root, false).is_ok());

    // Break it: an upward import and a circle.
    write("crates/demo/src/base.rs", "pub struct Mesh;\npub fn f() { crate::top::run() }\n");
    let (text, n) = layers::report(&root, false);
    assert_eq!(n, 2, "{text}");
    assert!(text.contains("\ncrates/demo/src/base.rs:2: `crate::base` imports `crate::top`, declared in a higher layer of `crate`'s file (group 3 > 1)\n"), "{text}");
    assert!(
        text.contains("\ncrates/demo/src/base.rs:2: import circle: base.rs:2 → top.rs:1 → ops.rs:1 → base.rs\n"),
        "{text}"
    );
    assert!(layers::run(&root, false).is_err());
    std::fs::remove_dir_all(&root).unwrap();
}
