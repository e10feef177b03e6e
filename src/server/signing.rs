//! Requests between the nodes of one PostgreSQL store, signed (issue 57).
//!
//! Every node reads the same cluster key file (`serve --cluster-key-file`,
//! one key a line, each at least 32 characters). A node signs each request
//! it sends another with HMAC-SHA256 under the file's first key, over the
//! node it is for (its URL), the method, the path and query, the body's
//! SHA-256, a timestamp, a nonce, its own name and the caller it speaks
//! for; the key never travels. The
//! receiving node accepts a signature under any key of its file, within
//! [`REPLAY_WINDOW_S`] of its clock and with a nonce it has not seen in
//! that window, and then checks the caller against the route's need
//! itself. The database holds only each node's key fingerprint (the
//! SHA-256 of its signing key): reading it signs nothing.
//!
//! Rotation without downtime: add the new key as a second line on every
//! node (each rereads its file within a second), then move it first,
//! then remove the old one.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, RwLock};
use std::time::{Duration, Instant, SystemTime};

use axum::http::{HeaderMap, HeaderName, HeaderValue};
use hmac::{Hmac, Mac};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use super::error::ApiError;
use crate::auth::{Need, Token};

/// The sending node's name.
pub const NODE_HEADER: &str = "x-tunnelnav-node";
/// Unix seconds when it signed.
pub const TIMESTAMP_HEADER: &str = "x-tunnelnav-timestamp";
/// 128 random bits, hex: never accepted twice within the window.
pub const NONCE_HEADER: &str = "x-tunnelnav-nonce";
/// The caller it speaks for ([`Grant`] as JSON, hex).
pub const CALLER_HEADER: &str = "x-tunnelnav-caller";
/// HMAC-SHA256 of the request's canonical form, hex.
pub const SIGNATURE_HEADER: &str = "x-tunnelnav-signature";
/// How far a signed request's time may be from the receiver's clock, s.
pub const REPLAY_WINDOW_S: f64 = 30.0;
/// The shortest key accepted, characters.
pub const MIN_KEY_CHARS: usize = 32;
/// How often the key file is looked at for a change.
const REREAD: Duration = Duration::from_secs(1);

/// Why the cluster key file cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum KeyFileError {
    #[error("cluster key file {path}: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error(
        "cluster key file {path} holds no key (one a line, at least {MIN_KEY_CHARS} characters)"
    )]
    Empty { path: PathBuf },
    #[error(
        "cluster key file {path}, line {line}: a key of {chars} characters; at least {MIN_KEY_CHARS} (e.g. `openssl rand -hex 32`)"
    )]
    Short {
        path: PathBuf,
        line: usize,
        chars: usize,
    },
}

/// Who a node-to-node request speaks for, as signed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "grant", rename_all = "snake_case")]
pub enum Grant {
    /// The sending node had no tokens (access open).
    Open,
    /// A token the sending node checked: its id in the shared store (the
    /// receiving node reads its scope there) and its name.
    Token { id: i64, name: String },
    /// Readings the sending node took in itself (its MQTT subscription, a
    /// WebSocket whose token it checked): ingest only.
    Node,
}

impl Grant {
    /// The grant of a request the caller's `token` (or none: open) made.
    pub fn of(token: Option<&Token>) -> Grant {
        match token {
            None => Grant::Open,
            Some(token) => Grant::Token {
                id: token.id,
                name: token.name.clone(),
            },
        }
    }

    /// Whether a node's own grant covers `need` (ingest only).
    pub fn node_allows(need: &Need) -> bool {
        matches!(need, Need::Nothing | Need::Ingest(_))
    }
}

/// A request as signed.
#[derive(Debug, Clone, Copy)]
pub struct Signable<'a> {
    /// The node it is for: the URL it advertises (a request signed for one
    /// node is refused by the others).
    pub to: &'a str,
    pub method: &'a str,
    /// The path and query, as sent.
    pub target: &'a str,
    pub body: &'a [u8],
}

/// The keys read from the file, and when.
struct Loaded {
    keys: Vec<Vec<u8>>,
    modified: Option<SystemTime>,
    looked: Instant,
}

/// This node's cluster keys and the nonces seen within the window.
pub struct ClusterKeys {
    file: Option<PathBuf>,
    loaded: RwLock<Loaded>,
    /// (node, nonce) → until when it is remembered (Unix seconds).
    seen: Mutex<HashMap<(String, String), f64>>,
}

impl std::fmt::Debug for ClusterKeys {
    /// The file and the key's fingerprint, never a key.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ClusterKeys")
            .field("file", &self.file)
            .field("fingerprint", &self.fingerprint())
            .finish()
    }
}

/// Reads the keys of `path`: one a line, blank lines and `#` comments
/// left out.
fn read_keys(path: &Path) -> Result<(Vec<Vec<u8>>, Option<SystemTime>), KeyFileError> {
    let read = |source| KeyFileError::Read {
        path: path.to_path_buf(),
        source,
    };
    let modified = std::fs::metadata(path).map_err(read)?.modified().ok();
    let text = std::fs::read_to_string(path).map_err(read)?;
    let mut keys = Vec::new();
    for (index, line) in text.lines().enumerate() {
        let key = line.trim();
        if key.is_empty() || key.starts_with('#') {
            continue;
        }
        let chars = key.chars().count();
        if chars < MIN_KEY_CHARS {
            return Err(KeyFileError::Short {
                path: path.to_path_buf(),
                line: index + 1,
                chars,
            });
        }
        keys.push(key.as_bytes().to_vec());
    }
    if keys.is_empty() {
        return Err(KeyFileError::Empty {
            path: path.to_path_buf(),
        });
    }
    Ok((keys, modified))
}

/// The canonical form a signature covers.
fn canonical(
    request: &Signable<'_>,
    timestamp: &str,
    nonce: &str,
    node: &str,
    caller: &str,
) -> Vec<u8> {
    let body = hex::encode(Sha256::digest(request.body));
    [
        "tunnelnav-node-request-1",
        request.to,
        request.method,
        request.target,
        &body,
        timestamp,
        nonce,
        node,
        caller,
    ]
    .join("\n")
    .into_bytes()
}

fn mac(key: &[u8]) -> Hmac<Sha256> {
    // HMAC takes a key of any length.
    <Hmac<Sha256> as Mac>::new_from_slice(key).unwrap_or_else(|_| unreachable!())
}

impl ClusterKeys {
    /// The keys of `file`; none without one (this node then neither signs
    /// nor accepts another node's requests).
    pub fn load(file: Option<&Path>) -> Result<ClusterKeys, KeyFileError> {
        let (keys, modified) = match file {
            Some(path) => read_keys(path)?,
            None => (Vec::new(), None),
        };
        Ok(ClusterKeys {
            file: file.map(Path::to_path_buf),
            loaded: RwLock::new(Loaded {
                keys,
                modified,
                looked: Instant::now(),
            }),
            seen: Mutex::new(HashMap::new()),
        })
    }

    /// The keys now: the file is reread when it changed (looked at once a
    /// second); a file that became unreadable keeps the keys it had.
    fn keys(&self) -> Vec<Vec<u8>> {
        if let Some(path) = &self.file {
            let stale = self
                .loaded
                .read()
                .map(|l| l.looked.elapsed() >= REREAD)
                .unwrap_or(true);
            if stale && let Ok(mut loaded) = self.loaded.write() {
                loaded.looked = Instant::now();
                let modified = std::fs::metadata(path).and_then(|m| m.modified()).ok();
                if modified != loaded.modified {
                    match read_keys(path) {
                        Ok((keys, modified)) => {
                            tracing::info!(file = %path.display(), keys = keys.len(), "cluster keys reread");
                            (loaded.keys, loaded.modified) = (keys, modified);
                        }
                        Err(e) => {
                            // Said once a change, not every second.
                            loaded.modified = modified;
                            tracing::warn!(error = %e, "cluster keys kept as they were");
                        }
                    }
                }
            }
        }
        self.loaded
            .read()
            .map(|l| l.keys.clone())
            .unwrap_or_default()
    }

    /// Whether this node has a key to sign with.
    pub fn has_key(&self) -> bool {
        !self.keys().is_empty()
    }

    /// The SHA-256 (hex) of the key this node signs with, as the `nodes`
    /// table shows it; empty without a key.
    pub fn fingerprint(&self) -> String {
        self.keys()
            .first()
            .map(|key| hex::encode(Sha256::digest(key)))
            .unwrap_or_default()
    }

    /// The headers that sign `request` as node `node` for `grant` at
    /// `now_s`; `None` without a key.
    pub fn sign(
        &self,
        request: &Signable<'_>,
        node: &str,
        grant: &Grant,
        now_s: f64,
    ) -> Option<Vec<(HeaderName, HeaderValue)>> {
        let keys = self.keys();
        let key = keys.first()?;
        let timestamp = format!("{now_s:.3}");
        let nonce = hex::encode(rand::random::<[u8; 16]>());
        let caller = hex::encode(serde_json::to_vec(grant).ok()?);
        let mut signer = mac(key);
        signer.update(&canonical(request, &timestamp, &nonce, node, &caller));
        let signature = hex::encode(signer.finalize().into_bytes());
        let header = |name: &'static str, value: &str| {
            Some((
                HeaderName::from_static(name),
                HeaderValue::from_str(value).ok()?,
            ))
        };
        [
            header(NODE_HEADER, node),
            header(TIMESTAMP_HEADER, &timestamp),
            header(NONCE_HEADER, &nonce),
            header(CALLER_HEADER, &caller),
            header(SIGNATURE_HEADER, &signature),
        ]
        .into_iter()
        .collect()
    }

    /// The sending node and the grant of a request signed by another node,
    /// or why it is refused (401).
    pub fn verify(
        &self,
        headers: &HeaderMap,
        request: &Signable<'_>,
        now_s: f64,
    ) -> Result<(String, Grant), ApiError> {
        let text = |name: &str| headers.get(name).and_then(|v| v.to_str().ok());
        let node = text(NODE_HEADER).unwrap_or("");
        let refused = |why: &str| {
            ApiError::Unauthorized(format!("a request forwarded as node `{node}`: {why}"))
        };
        let (Some(timestamp), Some(nonce), Some(caller), Some(signature)) = (
            text(TIMESTAMP_HEADER),
            text(NONCE_HEADER),
            text(CALLER_HEADER),
            text(SIGNATURE_HEADER),
        ) else {
            return Err(refused("not signed (a node signs with the cluster key)"));
        };
        let keys = self.keys();
        if keys.is_empty() {
            return Err(refused(
                "this node has no cluster key (serve --cluster-key-file) to check it with",
            ));
        }
        let signature =
            hex::decode(signature).map_err(|_| refused("a signature that is not hex"))?;
        let signed = canonical(request, timestamp, nonce, node, caller);
        let valid = keys.iter().any(|key| {
            let mut checker = mac(key);
            checker.update(&signed);
            checker.verify_slice(&signature).is_ok()
        });
        if !valid {
            return Err(refused("its signature is not one of this cluster's keys"));
        }
        let sent_s: f64 = timestamp
            .parse()
            .map_err(|_| refused("a timestamp that is not a number"))?;
        if !sent_s.is_finite() || (now_s - sent_s).abs() > REPLAY_WINDOW_S {
            return Err(refused(&format!(
                "signed at {sent_s}, more than {REPLAY_WINDOW_S} s from this node's clock ({now_s:.3})"
            )));
        }
        let Ok(mut seen) = self.seen.lock() else {
            return Err(refused(
                "this node cannot tell a replay now (its nonce record failed)",
            ));
        };
        if seen.len() >= 4096 {
            seen.retain(|_, until| *until >= now_s);
        }
        let key = (node.to_string(), nonce.to_string());
        if seen.contains_key(&key) {
            return Err(refused("its nonce was used before (a replay)"));
        }
        seen.insert(key, now_s + 2.0 * REPLAY_WINDOW_S);
        drop(seen);
        let grant = hex::decode(caller)
            .ok()
            .and_then(|bytes| serde_json::from_slice::<Grant>(&bytes).ok())
            .ok_or_else(|| refused("a caller this release does not read"))?;
        Ok((node.to_string(), grant))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const KEY: &str = "0123456789abcdef0123456789abcdef";

    fn key_file(lines: &str) -> (tempfile::TempDir, ClusterKeys) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("cluster.key");
        std::fs::write(&path, lines).unwrap();
        let keys = ClusterKeys::load(Some(&path)).unwrap();
        (dir, keys)
    }

    fn headers(signed: Vec<(HeaderName, HeaderValue)>) -> HeaderMap {
        signed.into_iter().collect()
    }

    const REQUEST: Signable<'static> = Signable {
        to: "http://10.0.0.2:8080",
        method: "POST",
        target: "/api/v1/machines/m1/readings",
        body: b"{\"t\": 1}\n",
    };

    #[test]
    fn a_signed_request_is_accepted_once_and_names_its_caller() {
        let (_dir, keys) = key_file(KEY);
        let grant = Grant::Token {
            id: 7,
            name: "gw".into(),
        };
        let signed = headers(keys.sign(&REQUEST, "a", &grant, 1000.0).unwrap());
        assert_eq!(
            keys.verify(&signed, &REQUEST, 1010.0).unwrap(),
            ("a".to_string(), grant)
        );
        // The same request again: a replay.
        let again = keys
            .verify(&signed, &REQUEST, 1011.0)
            .unwrap_err()
            .to_string();
        assert!(again.contains("replay"), "{again}");
    }

    #[test]
    fn any_change_or_an_old_or_foreign_signature_is_refused() {
        let (_dir, keys) = key_file(KEY);
        let signed = headers(keys.sign(&REQUEST, "a", &Grant::Node, 1000.0).unwrap());
        let other_body = Signable {
            body: b"{\"t\": 2}\n",
            ..REQUEST
        };
        let other_path = Signable {
            target: "/api/v1/machines/m2/readings",
            ..REQUEST
        };
        let other_node = Signable {
            to: "http://10.0.0.3:8080",
            ..REQUEST
        };
        for changed in [other_body, other_path, other_node] {
            let error = keys
                .verify(&signed, &changed, 1000.0)
                .unwrap_err()
                .to_string();
            assert!(error.contains("not one of this cluster's keys"), "{error}");
        }
        // Another caller in the headers, the signature kept.
        let mut forged = signed.clone();
        let admin = Grant::Token {
            id: 1,
            name: "admin".into(),
        };
        forged.insert(
            CALLER_HEADER,
            HeaderValue::from_str(&hex::encode(serde_json::to_vec(&admin).unwrap())).unwrap(),
        );
        assert!(keys.verify(&forged, &REQUEST, 1000.0).is_err());
        // Outside the window.
        let late = keys
            .verify(&signed, &REQUEST, 1031.0)
            .unwrap_err()
            .to_string();
        assert!(late.contains("more than 30 s"), "{late}");
        // Signed under another key.
        let (_other_dir, other) = key_file("fedcba9876543210fedcba9876543210");
        let foreign = headers(other.sign(&REQUEST, "a", &Grant::Node, 1000.0).unwrap());
        assert!(keys.verify(&foreign, &REQUEST, 1000.0).is_err());
        // The fingerprint (what the database holds) signs nothing.
        let (_fp_dir, from_fingerprint) = key_file(&keys.fingerprint());
        let guessed = headers(
            from_fingerprint
                .sign(&REQUEST, "a", &Grant::Node, 1000.0)
                .unwrap(),
        );
        assert!(keys.verify(&guessed, &REQUEST, 1000.0).is_err());
        // Unsigned.
        let mut bare = HeaderMap::new();
        bare.insert(NODE_HEADER, HeaderValue::from_static("a"));
        let error = keys
            .verify(&bare, &REQUEST, 1000.0)
            .unwrap_err()
            .to_string();
        assert!(error.contains("not signed"), "{error}");
    }

    #[test]
    fn a_second_key_verifies_while_the_first_signs() {
        let old = "0123456789abcdef0123456789abcdef";
        let new = "fedcba9876543210fedcba9876543210";
        let (_a, rotating) = key_file(&format!("{new}\n{old}\n"));
        let (_b, old_only) = key_file(old);
        // A node still on the old key is heard by one that rotated.
        let from_old = headers(old_only.sign(&REQUEST, "b", &Grant::Open, 5.0).unwrap());
        assert!(rotating.verify(&from_old, &REQUEST, 5.0).is_ok());
        // One that rotated signs with the new key: the old-only node
        // does not accept it (it must take the new key first).
        let from_new = headers(rotating.sign(&REQUEST, "a", &Grant::Open, 5.0).unwrap());
        assert!(old_only.verify(&from_new, &REQUEST, 5.0).is_err());
        assert_eq!(
            rotating.fingerprint(),
            hex::encode(Sha256::digest(new.as_bytes()))
        );
    }

    #[test]
    fn a_changed_key_file_is_read_again_within_a_second() {
        let old = "0123456789abcdef0123456789abcdef";
        let new = "fedcba9876543210fedcba9876543210";
        let (dir, keys) = key_file(old);
        let path = dir.path().join("cluster.key");
        std::fs::write(&path, format!("{new}\n{old}\n")).unwrap();
        // A modification time the file system tells apart from the first.
        let file = std::fs::File::options().write(true).open(&path).unwrap();
        file.set_modified(SystemTime::now() + Duration::from_secs(5))
            .unwrap();
        std::thread::sleep(REREAD + Duration::from_millis(50));
        assert_eq!(
            keys.fingerprint(),
            hex::encode(Sha256::digest(new.as_bytes()))
        );
        // A file that became unreadable keeps the keys it had.
        std::fs::remove_file(&path).unwrap();
        std::thread::sleep(REREAD + Duration::from_millis(50));
        assert!(keys.has_key());
    }

    #[test]
    fn a_short_or_empty_key_file_is_refused_naming_the_line() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("k");
        std::fs::write(&path, "# keys\n\nshort\n").unwrap();
        let error = ClusterKeys::load(Some(&path)).err().unwrap().to_string();
        assert!(error.contains("line 3: a key of 5 characters"), "{error}");
        std::fs::write(&path, "# none\n").unwrap();
        assert!(matches!(
            ClusterKeys::load(Some(&path)),
            Err(KeyFileError::Empty { .. })
        ));
        let none = ClusterKeys::load(None).unwrap();
        assert!(!none.has_key());
        assert!(none.sign(&REQUEST, "a", &Grant::Open, 0.0).is_none());
    }

    #[test]
    fn a_node_grant_covers_ingest_only() {
        assert!(Grant::node_allows(&Need::Ingest("m".into())));
        assert!(!Grant::node_allows(&Need::Read));
        assert!(!Grant::node_allows(&Need::Admin));
        assert!(!Grant::node_allows(&Need::Acknowledge));
    }
}
