//! A file server for tests over HTTP (issue 42), on a free port of 127.0.0.1, that adds a delay
//! to every answer and meets each request with the fault a rule picks: shared by tests/http.rs
//! and the viewer's test of a server whose chunks come back broken (tests/viewer.rs).

#![allow(dead_code)]

use std::collections::HashMap;
use std::io::{BufRead as _, BufReader, Write as _};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// What the server does with one request.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Fault {
    /// Answers as a file server does.
    None,
    /// 404 Not Found.
    NotFound,
    /// 500 Internal Server Error.
    Error,
    /// Promises the whole value and sends half, then closes.
    Truncate,
    /// Sends half, then says nothing for 5 s.
    Stall,
    /// Answers 200 with the value's length of bytes that decode as nothing: a broken chunk.
    Garbage,
}

/// Which fault a request meets: given its path and how many times that path was asked before.
pub type Rule = dyn Fn(&str, usize) -> Fault + Send + Sync;

pub struct State {
    root: PathBuf,
    delay: Duration,
    rule: Box<Rule>,
    asked: Mutex<HashMap<String, usize>>,
    in_flight: AtomicUsize,
    pub max_in_flight: AtomicUsize,
}

/// A file server over a folder, on a free port of 127.0.0.1, serving until the test ends.
pub struct Server {
    pub base: String,
    pub state: Arc<State>,
}

impl Server {
    pub fn start(
        root: &Path,
        delay_ms: u64,
        rule: impl Fn(&str, usize) -> Fault + Send + Sync + 'static,
    ) -> Server {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let base = format!("http://{}", listener.local_addr().unwrap());
        let state = Arc::new(State {
            root: root.to_path_buf(),
            delay: Duration::from_millis(delay_ms),
            rule: Box::new(rule),
            asked: Mutex::new(HashMap::new()),
            in_flight: AtomicUsize::new(0),
            max_in_flight: AtomicUsize::new(0),
        });
        let s = state.clone();
        std::thread::spawn(move || {
            for conn in listener.incoming().flatten() {
                let s = s.clone();
                std::thread::spawn(move || serve(&s, conn));
            }
        });
        Server { base, state }
    }

    /// The URL of `name` under the served folder.
    pub fn url(&self, name: &str) -> String {
        format!("{}/{name}", self.base)
    }

    /// The fewest requests any one path that holds `part` met (None when none was asked).
    pub fn fewest(&self, part: &str) -> Option<usize> {
        let asked = self.state.asked.lock().unwrap();
        asked
            .iter()
            .filter(|(k, _)| k.contains(part))
            .map(|(_, n)| *n)
            .min()
    }

    /// Requests for paths that hold `part`.
    pub fn asked(&self, part: &str) -> usize {
        let asked = self.state.asked.lock().unwrap();
        asked
            .iter()
            .filter(|(k, _)| k.contains(part))
            .map(|(_, n)| n)
            .sum()
    }
}

/// Answers the requests of one kept-alive connection.
fn serve(s: &State, conn: TcpStream) {
    let mut reader = BufReader::new(conn.try_clone().unwrap());
    let mut out = conn;
    loop {
        let mut line = String::new();
        if reader.read_line(&mut line).unwrap_or(0) == 0 {
            return;
        }
        let mut parts = line.split_whitespace();
        let method = parts.next().unwrap_or("").to_string();
        let path = parts.next().unwrap_or("/").to_string();
        let mut range = None;
        loop {
            let mut h = String::new();
            if reader.read_line(&mut h).unwrap_or(0) == 0 {
                return;
            }
            if h.trim().is_empty() {
                break;
            }
            if let Some((k, v)) = h.split_once(':') {
                if k.eq_ignore_ascii_case("range") {
                    range = Some(v.trim().to_string());
                }
            }
        }
        let n = s.in_flight.fetch_add(1, Ordering::SeqCst) + 1;
        s.max_in_flight.fetch_max(n, Ordering::SeqCst);
        std::thread::sleep(s.delay);
        let seen = {
            let mut asked = s.asked.lock().unwrap();
            let e = asked.entry(path.clone()).or_insert(0);
            *e += 1;
            *e - 1
        };
        let fault = (s.rule)(&path, seen);
        let keep = answer(s, &mut out, &method, &path, range.as_deref(), fault);
        s.in_flight.fetch_sub(1, Ordering::SeqCst);
        if !keep {
            return;
        }
    }
}

/// Writes one answer; whether the connection stays open.
fn answer(
    s: &State,
    out: &mut TcpStream,
    method: &str,
    path: &str,
    range: Option<&str>,
    fault: Fault,
) -> bool {
    let file = s.root.join(path.trim_start_matches('/'));
    let body = match std::fs::read(&file) {
        Ok(b) if !path.contains("..") && fault != Fault::NotFound => b,
        _ => {
            let _ = write!(out, "HTTP/1.1 404 Not Found\r\nContent-Length: 0\r\n\r\n");
            return true;
        }
    };
    if fault == Fault::Error {
        let _ = write!(
            out,
            "HTTP/1.1 500 Internal Server Error\r\nContent-Length: 5\r\n\r\noops!"
        );
        return true;
    }
    let (status, part) = match range.and_then(|r| byte_range(r, body.len())) {
        Some((a, b)) => ("206 Partial Content", &body[a..b]),
        None => ("200 OK", &body[..]),
    };
    let _ = write!(
        out,
        "HTTP/1.1 {status}\r\nContent-Length: {}\r\n\r\n",
        part.len()
    );
    if method == "HEAD" {
        return true;
    }
    let garbage: Vec<u8>;
    let part = match fault {
        Fault::Garbage => {
            garbage = (0..part.len()).map(|i| (i * 131 + 7) as u8).collect();
            &garbage[..]
        }
        _ => part,
    };
    match fault {
        Fault::Truncate => {
            let _ = out.write_all(&part[..part.len() / 2]);
            false
        }
        Fault::Stall => {
            let _ = out.write_all(&part[..part.len() / 2]);
            let _ = out.flush();
            std::thread::sleep(Duration::from_secs(5));
            false
        }
        _ => out.write_all(part).is_ok(),
    }
}

/// The bytes `bytes=a-b`, `bytes=a-` or `bytes=-n` of a value of `len`.
fn byte_range(r: &str, len: usize) -> Option<(usize, usize)> {
    let (a, b) = r.strip_prefix("bytes=")?.split_once('-')?;
    if a.is_empty() {
        return Some((len - b.parse::<usize>().ok()?.min(len), len));
    }
    let a: usize = a.parse().ok()?;
    let b = if b.is_empty() {
        len
    } else {
        b.parse::<usize>().ok()? + 1
    };
    (a <= b && b <= len).then_some((a, b))
}
