//! File helpers shared by every writer and reader of the crate: regular-file reads, atomic
//! file and folder writes, and the FNV-1a content hash of view-set manifests. Re-exported
//! from the `io` module.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use crate::error::{Error, Result};

/// Reads a whole input file after checking that it is a regular file: a folder, a FIFO or
/// a device such as `/dev/zero` (which never ends) is refused by name instead of read.
pub(crate) fn read_input(path: &Path) -> Result<Vec<u8>> {
    regular_file(path)?;
    std::fs::read(path).map_err(|e| Error::io(path, e))
}

/// The metadata of the input file `path` when it is a regular file (links followed); a
/// folder, a FIFO (opening one blocks until something writes to it) or a device is refused
/// by name before anything opens it.
pub(crate) fn regular_file(path: &Path) -> Result<std::fs::Metadata> {
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if !meta.is_file() {
        let what = if meta.is_dir() { "a folder" } else { "not a regular file (a device or pipe?)" };
        return Err(Error::format(path, "file", format!("a regular file, but it is {what}")));
    }
    Ok(meta)
}

/// A temporary path beside `path` (same directory, so a rename is atomic).
fn temp_path(path: &Path) -> PathBuf {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    path.with_file_name(format!(".{name}.{}.tmp", std::process::id()))
}

/// Writes several files as one: first checks that no destination is a folder, then writes
/// every file to a temporary name beside it, and only when all are written renames them
/// into place, in order (put the file that refers to the others last). On any error the
/// temporaries are removed and no destination has been touched.
pub fn write_atomic_all(files: &[(&Path, &[u8])]) -> Result<()> {
    for (path, _) in files {
        if path.is_dir() {
            return Err(Error::invalid(format!("output {}", path.display()), "a file name, but it is a folder"));
        }
    }
    let temps: Vec<PathBuf> = files.iter().map(|(path, _)| temp_path(path)).collect();
    let written = files.iter().zip(&temps).try_for_each(|((path, bytes), tmp)| {
        let mut file = File::create(tmp).map_err(|e| Error::io(path, e))?;
        file.write_all(bytes).and_then(|()| file.flush()).map_err(|e| Error::io(path, e))
    });
    if let Err(e) = written {
        for tmp in &temps {
            let _ = std::fs::remove_file(tmp);
        }
        return Err(e);
    }
    for (i, ((path, _), tmp)) in files.iter().zip(&temps).enumerate() {
        if let Err(e) = std::fs::rename(tmp, path) {
            for tmp in &temps[i..] {
                let _ = std::fs::remove_file(tmp);
            }
            return Err(Error::io(path, e));
        }
    }
    Ok(())
}

/// The checks every output folder that a command replaces as a whole shares, made before any
/// work: `dir` names a folder (not `.`, `..` or a root), its parent exists, and it is not a
/// file. Returns whether `dir` exists (then the caller checks what it holds before it may be
/// replaced).
pub fn replaceable_folder(dir: &Path) -> Result<bool> {
    let field = || format!("output folder {}", dir.display());
    if dir.file_name().is_none() {
        return Err(Error::invalid(field(), "a folder name (not `.`, `..` or a root)"));
    }
    if let Some(file) = dir.parent().and_then(file_in_the_way) {
        return Err(Error::invalid(
            field(),
            format!("a folder whose missing parents can be created, but {} is a file", file.display()),
        ));
    }
    match std::fs::symlink_metadata(dir) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(false),
        Err(e) => Err(Error::io(dir, e)),
        Ok(m) if !m.is_dir() => Err(Error::invalid(field(), "a folder, but it is a file")),
        Ok(_) => Ok(true),
    }
}

/// The nearest existing ancestor of `dir` (itself included) when it is not a folder: what
/// would keep `create_dir_all(dir)` from creating the missing folders. `None` when every
/// missing folder can be created under an existing one (or `dir` exists as a folder).
pub fn file_in_the_way(dir: &Path) -> Option<PathBuf> {
    for ancestor in dir.ancestors().filter(|a| !a.as_os_str().is_empty()) {
        match std::fs::metadata(ancestor) {
            Ok(m) if m.is_dir() => return None,
            Ok(_) => return Some(ancestor.to_path_buf()),
            Err(_) => continue,
        }
    }
    None
}

/// Writes a folder atomically: `fill` writes the folder's files into a fresh staging folder
/// beside `dir` (`.<name>.partial-<pid>-<n>`), which then replaces `dir` as a whole (an
/// existing `dir` is moved aside first and deleted only once the new one is in place). On
/// any error the staging folder is removed and `dir` is left as it was, so a reader never
/// sees a folder mixing two writes. Missing parent folders are created first (as `mkdir -p`
/// would; the atomic switch happens in the last one). The caller decides whether `dir` may be
/// replaced; a file at `dir` or in the way of its parents is refused before `fill` runs, see
/// [`replaceable_folder`].
///
/// `manifest` names the file (or folder) in `dir` that `fill` writes last and readers check
/// first: the view set's `cameras.json`, the dataset's `dataset.json`, a model's
/// `model_index.json`. It matters when `dir` is a mount point (a container or Kubernetes
/// volume), which cannot be renamed: there the staging folder is made *inside* `dir`
/// (`.partial-<pid>-<n>`), filled, and then switched in entry by entry — the old manifest
/// removed first, then the old entries, then the new ones moved in with the manifest last —
/// so at every moment `dir` holds either the complete old run, the complete new run, or a
/// folder without its manifest that every reader refuses, never a mix of two runs that
/// passes for one. The long work (`fill`) happens before anything old is touched; only an
/// I/O error during the switch itself (renames within one file system) can leave the folder
/// without its manifest, and the error says so.
pub fn write_dir_atomic(dir: impl AsRef<Path>, manifest: &str, fill: impl FnOnce(&Path) -> Result<()>) -> Result<()> {
    let dir = dir.as_ref();
    let exists = replaceable_folder(dir)?;
    if exists && is_mount_point(dir) {
        return write_dir_in_place(dir, manifest, fill);
    }
    if let Some(parent) = dir.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
    }
    let staging = sibling(dir, "partial")?;
    let written = std::fs::create_dir(&staging).map_err(|e| Error::io(&staging, e)).and_then(|()| fill(&staging));
    if let Err(e) = written {
        let _ = std::fs::remove_dir_all(&staging);
        return Err(e);
    }
    replace_dir(&staging, dir)
}

/// Whether the existing folder `dir` is a mount point, which `rename` cannot move ("Device
/// or resource busy"). On Linux from `/proc/self/mountinfo`, which also lists bind mounts
/// of a folder of the same file system (as container runtimes make them); elsewhere, and
/// when that file cannot be read, by the folder's device differing from its parent's.
pub fn is_mount_point(dir: &Path) -> bool {
    let Ok(canonical) = dir.canonicalize() else { return false };
    // A root is always one.
    if canonical.parent().is_none() {
        return true;
    }
    if let Ok(info) = std::fs::read_to_string("/proc/self/mountinfo") {
        // Field 5 is the mount point, with space, tab, newline and backslash octal-escaped.
        return info
            .lines()
            .filter_map(|line| line.split(' ').nth(4))
            .any(|m| Path::new(&unescape_octal(m)) == canonical);
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        let parent = canonical.parent().unwrap_or(&canonical);
        if let (Ok(a), Ok(b)) = (std::fs::metadata(&canonical), std::fs::metadata(parent)) {
            return a.dev() != b.dev();
        }
    }
    false
}

/// `\040`-style octal escapes of `/proc/self/mountinfo` decoded.
fn unescape_octal(field: &str) -> String {
    let bytes = field.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        let octal =
            bytes.get(i + 1..i + 4).filter(|d| bytes[i] == b'\\' && d.iter().all(|c| (b'0'..=b'7').contains(c)));
        match octal {
            Some(d) => {
                out.push(d.iter().fold(0u8, |v, c| v.wrapping_mul(8).wrapping_add(c - b'0')));
                i += 4;
            }
            None => {
                out.push(bytes[i]);
                i += 1;
            }
        }
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// [`write_dir_atomic`] for a `dir` that cannot be renamed (a mount point): staging inside
/// `dir`, then the switch described there, manifest out first and in last.
fn write_dir_in_place(dir: &Path, manifest: &str, fill: impl FnOnce(&Path) -> Result<()>) -> Result<()> {
    let staging_name = format!(".partial-{}", unique_suffix());
    let staging = dir.join(&staging_name);
    let written = std::fs::create_dir(&staging).map_err(|e| Error::io(&staging, e)).and_then(|()| fill(&staging));
    if let Err(e) = written {
        let _ = std::fs::remove_dir_all(&staging);
        return Err(e);
    }
    let switch = || -> std::io::Result<()> {
        remove_entry(&dir.join(manifest))?;
        for entry in std::fs::read_dir(dir)? {
            let entry = entry?;
            if entry.file_name() != staging_name.as_str() {
                remove_entry(&entry.path())?;
            }
        }
        let mut entries: Vec<_> =
            std::fs::read_dir(&staging)?.map(|e| e.map(|e| e.file_name())).collect::<std::io::Result<_>>()?;
        // The manifest last: until it arrives, readers refuse the folder.
        entries.sort_by_key(|name| name == manifest);
        for name in entries {
            std::fs::rename(staging.join(&name), dir.join(&name))?;
        }
        std::fs::remove_dir(&staging)
    };
    switch().map_err(|e| {
        let _ = std::fs::remove_dir_all(&staging);
        Error::invalid(
            format!("output folder {}", dir.display()),
            format!(
                "a mount point whose contents could be switched to the new run, but that failed ({e}): it holds no \
                 {manifest} now, so readers refuse it; run the command again"
            ),
        )
    })
}

/// Removes a file, link or folder at `path`; nothing there is not an error.
fn remove_entry(path: &Path) -> std::io::Result<()> {
    let result = match std::fs::symlink_metadata(path) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(e),
        Ok(m) if m.is_dir() => std::fs::remove_dir_all(path),
        Ok(_) => std::fs::remove_file(path),
    };
    match result {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        other => other,
    }
}

/// A path beside `dir` for a staging or backup folder: `.<name>.<what>-<pid>-<n>`.
fn sibling(dir: &Path, what: &str) -> Result<PathBuf> {
    let name = dir
        .file_name()
        .ok_or_else(|| Error::invalid(format!("output folder {}", dir.display()), "a folder name"))?
        .to_string_lossy()
        .into_owned();
    Ok(dir.with_file_name(format!(".{name}.{what}-{}", unique_suffix())))
}

/// `<pid>-<n>` for staging and backup folder names: no two writes running at once share one
/// (the process id, and the clock's nanoseconds within a process).
fn unique_suffix() -> String {
    let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.subsec_nanos());
    format!("{}-{nanos}", std::process::id())
}

/// Moves the finished folder `staging` to `dir`, replacing an existing `dir` (moved aside
/// first and deleted only once `staging` is in place; put back if the move fails).
fn replace_dir(staging: &Path, dir: &Path) -> Result<()> {
    let fail = |e: std::io::Error| {
        let _ = std::fs::remove_dir_all(staging);
        Error::io(dir, e)
    };
    if !dir.exists() {
        return std::fs::rename(staging, dir).map_err(fail);
    }
    let old = sibling(dir, "old")?;
    std::fs::rename(dir, &old).map_err(fail)?;
    if let Err(e) = std::fs::rename(staging, dir) {
        let _ = std::fs::rename(&old, dir);
        return Err(fail(e));
    }
    std::fs::remove_dir_all(&old).map_err(|e| Error::io(&old, e))
}

/// The 64-bit FNV-1a hash of `bytes` as 16 lower-case hex digits: the content check that
/// view-set manifests (`cameras.json`) and batch item records store beside file sizes. Not
/// cryptographic; it catches files from another run or a torn write, not tampering.
pub fn fnv1a64(bytes: &[u8]) -> String {
    let hash =
        bytes.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &b| (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3));
    format!("{hash:016x}")
}

/// Writes a file atomically: `write` fills a buffered temporary file beside `path`,
/// which is then flushed and renamed onto `path`. On any error the temporary file is
/// removed and `path` is left untouched.
pub fn write_atomic(path: impl AsRef<Path>, write: impl FnOnce(&mut BufWriter<File>) -> Result<()>) -> Result<()> {
    let path = path.as_ref();
    let tmp = temp_path(path);
    let result = (|| {
        let file = File::create(&tmp).map_err(|e| Error::io(path, e))?;
        let mut w = BufWriter::new(file);
        write(&mut w)?;
        w.flush().map_err(|e| Error::io(path, e))?;
        drop(w);
        std::fs::rename(&tmp, path).map_err(|e| Error::io(path, e))
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}
