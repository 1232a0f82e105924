//! Output-path checks for front ends such as the `wonder3d` command line: each one fails in
//! a millisecond, before any long work, when an output path cannot take what a command will
//! write there (a wrong extension, a missing parent folder, a folder where a file goes, two
//! outputs on one file).

use std::path::{Path, PathBuf};

use w3d_core::{Error, Result, ViewSet};

/// The files that saving a mesh to `path` writes: `path` itself, and for `.obj` also
/// `<stem>.mtl` and `<stem>.png` beside it (written when the mesh has a texture).
pub fn mesh_output_files(path: impl AsRef<Path>) -> Vec<PathBuf> {
    let path = path.as_ref();
    let mut files = Vec::new();
    if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("obj")) {
        let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        files.push(path.with_file_name(format!("{stem}.png")));
        files.push(path.with_file_name(format!("{stem}.mtl")));
    }
    files.push(path.to_path_buf());
    files
}

/// Fails unless `path` can take a mesh: a supported extension (`.glb`, `.obj`, `.ply`;
/// `.gltf` is read-only and refused) and, for every file the save writes
/// ([`mesh_output_files`]), an existing parent folder and no folder of that name. Call it
/// before long work so a typo fails in a millisecond, not after the reconstruction.
pub fn check_mesh_output(path: impl AsRef<Path>) -> Result<()> {
    let path = path.as_ref();
    let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
    if !matches!(ext.as_deref(), Some("glb" | "obj" | "ply")) {
        return Err(Error::invalid(
            format!("output {}", path.display()),
            "a .glb, .obj or .ply file name (the mesh formats this library writes)",
        ));
    }
    mesh_output_files(path).iter().try_for_each(|f| check_parent(f))
}

/// Fails unless the folder that would hold `path` exists (an empty parent is the working
/// directory) and `path` itself is not a folder.
pub fn check_parent(path: &Path) -> Result<()> {
    if path.is_dir() {
        return Err(Error::invalid(format!("output {}", path.display()), "a file name, but it is a folder"));
    }
    match path.parent() {
        Some(parent) if !parent.as_os_str().is_empty() && !parent.is_dir() => Err(Error::invalid(
            format!("output {}", path.display()),
            format!("an existing folder {}; create it first", parent.display()),
        )),
        _ => Ok(()),
    }
}

/// Fails unless `dir` can receive a view-set folder (`wonder3d render`, `generate`, `run
/// --views`): see [`ViewSet::check_output_dir`] (a new folder, its missing parents created
/// when it is written, or an earlier view-set folder, which the new set replaces as a whole).
pub fn check_out_dir(dir: impl AsRef<Path>) -> Result<()> {
    ViewSet::check_output_dir(dir)
}

/// Fails unless `dir` can hold named output files (created if missing, with any missing
/// parents, like `mkdir -p`): not a file, and no file in the way of its parents.
pub fn check_out_folder(dir: impl AsRef<Path>) -> Result<()> {
    let dir = dir.as_ref();
    if dir.exists() && !dir.is_dir() {
        return Err(Error::invalid(format!("output folder {}", dir.display()), "a folder, but it is a file"));
    }
    match dir.parent().and_then(w3d_core::io::file_in_the_way) {
        Some(file) => Err(Error::invalid(
            format!("output folder {}", dir.display()),
            format!("a folder whose missing parents can be created, but {} is a file", file.display()),
        )),
        None => Ok(()),
    }
}

/// Checks every output of a command before any work, each given with the flag or argument
/// that named it (`("--out", path)`): the mesh ([`check_mesh_output`]), the JSON report
/// ([`check_report_output`]) and the view-set folder ([`check_out_dir`]) when given; that no
/// two files are the same ([`check_distinct`]: the mesh's `.mtl` / `.png` included), and that
/// neither file lies inside the view-set folder (which is replaced as a whole). Errors start
/// with the name ([`for_flag`]).
pub fn check_outputs(mesh: (&str, &Path), report: Option<(&str, &Path)>, views: Option<(&str, &Path)>) -> Result<()> {
    for_flag(mesh.0, check_mesh_output(mesh.1))?;
    if let Some((name, report)) = report {
        for_flag(name, check_report_output(report))?;
    }
    if let Some((name, views)) = views {
        for_flag(name, check_out_dir(views))?;
    }
    let written = mesh_output_files(mesh.1);
    let mut files: Vec<(&str, &Path)> = written.iter().map(|f| (mesh.0, f.as_path())).collect();
    files.extend(report);
    check_distinct(&files, &[])?;
    if let Some((name, views)) = views
        && let Some((flag, file)) = files.iter().find(|(_, f)| absolute(f).parent() == Some(absolute(views).as_path()))
    {
        return Err(Error::invalid(
            *flag,
            format!(
                "a file outside the {name} folder {} (which is replaced as a whole), got {}",
                views.display(),
                file.display()
            ),
        ));
    }
    Ok(())
}

/// Fails unless `path` can take a JSON report: a `.json` name in an existing folder (a report
/// named like a mesh or an image is a slip of the command line, not a wish).
pub fn check_report_output(path: impl AsRef<Path>) -> Result<()> {
    let path = path.as_ref();
    if !path.extension().is_some_and(|e| e.eq_ignore_ascii_case("json")) {
        return Err(Error::invalid(format!("output {}", path.display()), "a .json file name (the report is JSON)"));
    }
    check_parent(path)
}

/// `result` with the flag or argument `name` that gave the path in front of its error's
/// field (`--out: output folder X: expected …`), so the message says which option to fix;
/// errors that already start with it, and I/O errors (which name the path), pass unchanged.
pub fn for_flag<T>(name: &str, result: Result<T>) -> Result<T> {
    result.map_err(|e| match e {
        Error::Invalid { field, expected } if !field.starts_with(name) => {
            Error::Invalid { field: format!("{name}: {field}"), expected }
        }
        other => other,
    })
}

/// Fails when two of a command's `outputs` are the same file, or an output is one of its
/// `inputs`: each entry names the flag or argument (`"--mask-out"`, `"IMAGE"`) and its path.
/// Paths are compared absolute, and through the file system where both exist (a link, or
/// `a/../b`, names the same file). Call it with the other checks, before any work: otherwise
/// the second write silently replaces the first, or the input is gone before it is read.
pub fn check_distinct(outputs: &[(&str, &Path)], inputs: &[(&str, &Path)]) -> Result<()> {
    let same = |a: &Path, b: &Path| match (std::fs::canonicalize(a), std::fs::canonicalize(b)) {
        (Ok(a), Ok(b)) => a == b,
        _ => absolute(a) == absolute(b),
    };
    for (i, &(name, path)) in outputs.iter().enumerate() {
        if let Some(&(other, _)) = outputs[..i].iter().find(|(_, p)| same(p, path)) {
            return Err(Error::invalid(
                name,
                format!("a file of its own ({} is also the {other} output)", path.display()),
            ));
        }
        if let Some(&(input, _)) = inputs.iter().find(|(_, p)| same(p, path)) {
            return Err(Error::invalid(
                name,
                format!("a file other than the {input} input ({} would be overwritten)", path.display()),
            ));
        }
    }
    Ok(())
}

/// Fails when one of `inputs` lies inside `folder`, an output folder that is replaced as a
/// whole (a view-set folder): the input would be deleted with the folder's old contents, or
/// replaced by an output of the same name. `(name, path)` as in [`check_distinct`].
pub fn check_inputs_outside(folder: (&str, &Path), inputs: &[(&str, &Path)]) -> Result<()> {
    let (flag, folder) = folder;
    let dir = resolved(folder);
    for &(input, path) in inputs {
        if resolved(path).starts_with(&dir) {
            return Err(Error::invalid(
                flag,
                format!(
                    "a folder that does not hold the {input} input ({} is replaced as a whole, {} with it)",
                    folder.display(),
                    path.display()
                ),
            ));
        }
    }
    Ok(())
}

/// Fails when the output folder `folder` is one of the input folders `inputs` or lies inside
/// one: the run's files would land among the input's (a model or training-set folder that
/// then holds a foreign run, which later commands refuse or misread). `(name, path)` as in
/// [`check_distinct`].
pub fn check_folder_outside_inputs(folder: (&str, &Path), inputs: &[(&str, &Path)]) -> Result<()> {
    let (flag, folder) = folder;
    let out = resolved(folder);
    for &(input, path) in inputs {
        if out.starts_with(resolved(path)) {
            return Err(Error::invalid(
                flag,
                format!(
                    "a folder outside the {input} input ({} lies in {}, which would receive the run's files)",
                    folder.display(),
                    path.display()
                ),
            ));
        }
    }
    Ok(())
}

/// `path` absolute, as written (no links followed; unchanged when the working directory is
/// unknown).
fn absolute(path: &Path) -> PathBuf {
    std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf())
}

/// `path` absolute and, where it exists, with links and `..` resolved: what the folder checks
/// compare, so `a/../b` or a link into a folder counts as inside it.
pub(crate) fn resolved(path: &Path) -> PathBuf {
    std::fs::canonicalize(path).unwrap_or_else(|_| absolute(path))
}

/// Fails unless `path` can take a PNG: a `.png` name in an existing folder. Call it before
/// the work.
pub fn check_png_output(path: impl AsRef<Path>) -> Result<()> {
    let path = path.as_ref();
    let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
    if ext.as_deref() != Some("png") {
        return Err(Error::invalid(
            format!("output {}", path.display()),
            "a .png file name (RGBA images are written as PNG)",
        ));
    }
    check_parent(path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn output_folders_may_exist_but_not_be_files() {
        let dir = tempfile::tempdir().unwrap();
        // An existing folder (a second demo run into the same folder) is fine, a new one too.
        check_out_folder(dir.path()).unwrap();
        check_out_folder(dir.path().join("new")).unwrap();
        let file = dir.path().join("file");
        std::fs::write(&file, "x").unwrap();
        assert!(check_out_folder(&file).unwrap_err().to_string().contains("it is a file"));
        // Missing parents are fine (created when the folder is); a file in their way is not.
        check_out_folder(dir.path().join("a/b")).unwrap();
        let err = check_out_folder(file.join("a/b")).unwrap_err().to_string();
        assert!(err.contains("file is a file"), "{err}");
    }

    #[test]
    fn every_output_is_checked_together() {
        let dir = tempfile::tempdir().unwrap();
        let p = |name: &str| dir.path().join(name);
        let (mesh, views) = (p("m.glb"), p("views"));
        check_outputs(("--out", &mesh), Some(("--report", &p("r.json"))), Some(("--views", &views))).unwrap();
        check_outputs(("--out", &p("m.obj")), None, None).unwrap();
        let err = |mesh: &str, report: Option<&str>, views: Option<&str>| {
            let (mesh, report, views) = (p(mesh), report.map(p), views.map(p));
            check_outputs(
                ("--out", &mesh),
                report.as_deref().map(|r| ("--report", r)),
                views.as_deref().map(|v| ("--views", v)),
            )
            .unwrap_err()
            .to_string()
        };
        assert!(err("m.stl", None, None).contains("--out: output"));
        assert!(err("m.stl", None, None).contains(".glb, .obj or .ply"));
        let same = err("m.glb", Some("m.glb"), None);
        assert!(same.contains("--report") && same.contains(".json file name"), "{same}");
        let same = err("m.obj", Some("m.png"), None);
        assert!(same.contains("--report") && same.contains(".json"), "{same}");
        std::fs::create_dir(p("views")).unwrap();
        let taken = err("views/m.glb", None, Some("views"));
        assert!(taken.contains("--out") && taken.contains("replaced as a whole"), "{taken}");
        assert!(err("m.glb", Some("no/r.json"), None).contains("create it first"));
        // An OBJ whose texture name is taken by a folder is refused before any work.
        std::fs::create_dir(p("t.png")).unwrap();
        assert!(err("t.obj", None, None).contains("t.png"));
        assert_eq!(mesh_output_files(p("t.obj")), vec![p("t.png"), p("t.mtl"), p("t.obj")]);
        assert_eq!(mesh_output_files(p("t.glb")), vec![p("t.glb")]);
        // The same file twice, named by both flags.
        let twice = check_distinct(&[("--out", p("a.json").as_path()), ("--report", p("a.json").as_path())], &[])
            .unwrap_err()
            .to_string();
        assert!(twice.contains("--report") && twice.contains("--out"), "{twice}");
    }
}
