//! A Hugging Face Hub on loopback for the weights-by-Hub-id tests (the facade's `hub` group
//! and the CLI's `hub` group include this file): HTTP/1.1 on `std::net`, one request per
//! connection (`Connection: close`), serving model repositories in the Hub's URL layout —
//! the endpoints hf-hub 1.0 calls to resolve a revision, list a repository and download a file:
//!
//! - `GET /api/models/{owner}/{name}/revision/{revision}`: `{"id", "sha", "siblings"}` (404
//!   for an unknown repository or revision);
//! - `GET /api/models/{owner}/{name}/tree/{revision}[/{folder}]?recursive=true`: one page of
//!   `{"type": "file", "oid", "size", "path"}`;
//! - `HEAD` / `GET /{owner}/{name}/resolve/{revision}/{path}`: the file, with `ETag`,
//!   `X-Repo-Commit` and `Content-Length` (404 for a file the repository lacks or that is
//!   marked missing; a file marked to be cut sends half its body, then closes the connection,
//!   once).
//!
//! Every request is counted and logged (`METHOD /path?query`).
#![allow(dead_code)]

use std::collections::{BTreeMap, BTreeSet};
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

use wonder3d::core::io::fnv1a64;

/// A repository: its files at one commit.
#[derive(Clone, Default)]
pub struct Repo {
    /// The commit every revision name resolves to.
    pub commit: String,
    /// Path in the repository → contents.
    pub files: BTreeMap<String, Vec<u8>>,
}

impl Repo {
    /// Every file under `dir`, placed under `prefix` (`""` for the root).
    pub fn from_dir(dir: &Path, prefix: &str) -> Repo {
        let mut repo = Repo { commit: String::new(), files: BTreeMap::new() };
        repo.add_dir(dir, prefix);
        repo
    }

    /// Adds every file under `dir`, placed under `prefix`.
    pub fn add_dir(&mut self, dir: &Path, prefix: &str) {
        let mut stack = vec![(dir.to_path_buf(), prefix.trim_end_matches('/').to_owned())];
        while let Some((dir, prefix)) = stack.pop() {
            for entry in std::fs::read_dir(&dir).unwrap() {
                let entry = entry.unwrap();
                let name = entry.file_name().into_string().unwrap();
                let path = if prefix.is_empty() { name } else { format!("{prefix}/{name}") };
                if entry.file_type().unwrap().is_dir() {
                    stack.push((entry.path(), path));
                } else {
                    self.files.insert(path, std::fs::read(entry.path()).unwrap());
                }
            }
        }
    }

    /// The same repository with `path` holding `bytes`.
    pub fn with_file(mut self, path: &str, bytes: &[u8]) -> Repo {
        self.files.insert(path.to_owned(), bytes.to_vec());
        self
    }

    /// The same repository without `path`.
    pub fn without_file(mut self, path: &str) -> Repo {
        self.files.remove(path);
        self
    }
}

/// What the server serves and how it misbehaves.
#[derive(Default)]
struct State {
    repos: BTreeMap<String, Repo>,
    /// Files (`owner/name/path`) listed but answered 404 by `resolve`.
    missing: BTreeSet<String>,
    /// Files (`owner/name/path`) whose next `GET` is cut off after half the body.
    cut: BTreeSet<String>,
    log: Vec<String>,
}

/// The running server; it stops accepting when dropped.
pub struct HubServer {
    /// `http://127.0.0.1:PORT`.
    pub endpoint: String,
    state: Arc<Mutex<State>>,
    stop: Arc<AtomicBool>,
    port: u16,
}

impl HubServer {
    /// A server on a free loopback port.
    pub fn start() -> HubServer {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let port = listener.local_addr().unwrap().port();
        let state = Arc::new(Mutex::new(State::default()));
        let stop = Arc::new(AtomicBool::new(false));
        let (s, st) = (state.clone(), stop.clone());
        std::thread::spawn(move || {
            for stream in listener.incoming() {
                if st.load(Ordering::SeqCst) {
                    break;
                }
                let Ok(stream) = stream else { continue };
                let s = s.clone();
                std::thread::spawn(move || {
                    let _ = serve(stream, &s);
                });
            }
        });
        HubServer { endpoint: format!("http://127.0.0.1:{port}"), state, stop, port }
    }

    /// Serves `repo` as `id` (`owner/name`); its commit is derived from the id when empty.
    pub fn add(&self, id: &str, mut repo: Repo) -> String {
        if repo.commit.is_empty() {
            repo.commit = format!("{}{}{:08x}", fnv1a64(id.as_bytes()), fnv1a64(b"commit"), 7);
        }
        let commit = repo.commit.clone();
        self.state.lock().unwrap().repos.insert(id.to_owned(), repo);
        commit
    }

    /// `resolve` answers 404 for `file` of `id` though the listing has it.
    pub fn mark_missing(&self, id: &str, file: &str) {
        self.state.lock().unwrap().missing.insert(format!("{id}/{file}"));
    }

    /// The next `GET` of `file` of `id` sends half the body, then closes the connection.
    pub fn cut_next_download(&self, id: &str, file: &str) {
        self.state.lock().unwrap().cut.insert(format!("{id}/{file}"));
    }

    /// The requests served so far (`METHOD /path?query`), and forgets them.
    pub fn take_log(&self) -> Vec<String> {
        std::mem::take(&mut self.state.lock().unwrap().log)
    }

    /// The number of requests since the last [`HubServer::take_log`].
    pub fn requests(&self) -> usize {
        self.state.lock().unwrap().log.len()
    }
}

impl Drop for HubServer {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        let _ = TcpStream::connect(("127.0.0.1", self.port));
    }
}

/// Writes a response: status line, headers, `Connection: close`, the body unless `HEAD`.
fn respond(
    stream: &mut TcpStream,
    status: &str,
    headers: &[(&str, String)],
    body: &[u8],
    head: bool,
) -> std::io::Result<()> {
    let mut out = format!("HTTP/1.1 {status}\r\nConnection: close\r\nContent-Length: {}\r\n", body.len());
    for (name, value) in headers {
        out.push_str(&format!("{name}: {value}\r\n"));
    }
    out.push_str("\r\n");
    stream.write_all(out.as_bytes())?;
    if !head {
        stream.write_all(body)?;
    }
    stream.flush()
}

fn not_found(stream: &mut TcpStream, what: &str, head: bool) -> std::io::Result<()> {
    let body = format!("{{\"error\":\"{what} not found\"}}");
    respond(stream, "404 Not Found", &[("Content-Type", "application/json".into())], body.as_bytes(), head)
}

/// Serves one request on `stream`.
fn serve(mut stream: TcpStream, state: &Mutex<State>) -> std::io::Result<()> {
    let mut reader = BufReader::new(stream.try_clone()?);
    let mut line = String::new();
    reader.read_line(&mut line)?;
    let mut parts = line.split_whitespace();
    let (method, target) = (parts.next().unwrap_or("").to_owned(), parts.next().unwrap_or("").to_owned());
    let mut content_length = 0usize;
    loop {
        let mut header = String::new();
        if reader.read_line(&mut header)? == 0 || header == "\r\n" || header == "\n" {
            break;
        }
        if let Some((name, value)) = header.split_once(':')
            && name.eq_ignore_ascii_case("content-length")
        {
            content_length = value.trim().parse().unwrap_or(0);
        }
    }
    let mut body = vec![0; content_length];
    reader.read_exact(&mut body)?;
    let head = method == "HEAD";
    let (path, _query) = target.split_once('?').unwrap_or((&target, ""));
    state.lock().unwrap().log.push(format!("{method} {target}"));
    let segments: Vec<&str> = path.trim_start_matches('/').split('/').collect();
    // API: /api/models/{owner}/{name}/revision/{rev} and /api/models/{owner}/{name}/tree/{rev}[/{folder}].
    if let ["api", "models", owner, name, kind, revision, rest @ ..] = segments.as_slice() {
        let id = format!("{owner}/{name}");
        let repo = state.lock().unwrap().repos.get(&id).cloned();
        let Some(repo) = repo.filter(|r| *revision == "main" || *revision == r.commit) else {
            return not_found(&mut stream, "Repository or revision", head);
        };
        let json = match *kind {
            "revision" if rest.is_empty() => {
                let siblings: Vec<String> = repo.files.keys().map(|p| format!("{{\"rfilename\":\"{p}\"}}")).collect();
                format!("{{\"id\":\"{id}\",\"sha\":\"{}\",\"siblings\":[{}]}}", repo.commit, siblings.join(","))
            }
            "tree" => {
                let folder = rest.join("/");
                let prefix = if folder.is_empty() { String::new() } else { format!("{folder}/") };
                if !repo.files.keys().any(|p| p.starts_with(&prefix)) {
                    return not_found(&mut stream, "Folder", head);
                }
                let entries: Vec<String> = repo
                    .files
                    .iter()
                    .filter(|(p, _)| p.starts_with(&prefix))
                    .map(|(p, b)| {
                        format!(
                            "{{\"type\":\"file\",\"oid\":\"{}\",\"size\":{},\"path\":\"{p}\"}}",
                            fnv1a64(b),
                            b.len()
                        )
                    })
                    .collect();
                format!("[{}]", entries.join(","))
            }
            _ => return not_found(&mut stream, "Endpoint", head),
        };
        let headers = [("Content-Type", "application/json".to_owned())];
        return respond(&mut stream, "200 OK", &headers, json.as_bytes(), head);
    }
    // Files: /{owner}/{name}/resolve/{rev}/{path…}.
    if let [owner, name, "resolve", revision, rest @ ..] = segments.as_slice() {
        let id = format!("{owner}/{name}");
        let file = rest.join("/");
        let (repo, missing, cut) = {
            let mut s = state.lock().unwrap();
            let key = format!("{id}/{file}");
            let cut = !head && s.cut.remove(&key);
            (s.repos.get(&id).cloned(), s.missing.contains(&key), cut)
        };
        let Some(repo) = repo.filter(|r| *revision == "main" || *revision == r.commit) else {
            return not_found(&mut stream, "Repository or revision", head);
        };
        let Some(bytes) = repo.files.get(&file).filter(|_| !missing) else {
            let headers = [("X-Error-Code", "EntryNotFound".to_owned()), ("X-Repo-Commit", repo.commit.clone())];
            return respond(&mut stream, "404 Not Found", &headers, b"{\"error\":\"Entry not found\"}", head);
        };
        let headers = [
            ("ETag", format!("\"{}{}\"", fnv1a64(bytes), fnv1a64(file.as_bytes()))),
            ("X-Repo-Commit", repo.commit.clone()),
            ("Content-Type", "application/octet-stream".to_owned()),
        ];
        if cut {
            // The whole length announced, half the body sent, then the connection closed.
            let mut out = format!("HTTP/1.1 200 OK\r\nConnection: close\r\nContent-Length: {}\r\n", bytes.len());
            for (name, value) in &headers {
                out.push_str(&format!("{name}: {value}\r\n"));
            }
            out.push_str("\r\n");
            stream.write_all(out.as_bytes())?;
            stream.write_all(&bytes[..bytes.len() / 2])?;
            stream.flush()?;
            return stream.shutdown(std::net::Shutdown::Both);
        }
        return respond(&mut stream, "200 OK", &headers, bytes, head);
    }
    not_found(&mut stream, "Endpoint", head)
}
