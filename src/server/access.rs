//! Who may steer the daemon, and what a client may make it read.
//!
//! - **Binding.** A listener on anything but loopback needs an access token
//!   (`--token-file`); without one the daemon refuses to start unless told `--insecure`.
//! - **The token** is checked in constant time (SHA-256 of both sides, compared with
//!   [`subtle`]) on every mutating HTTP call (`Authorization: Bearer TOKEN`) and on a TCP pose
//!   connection's `hello` (its `token`), before any other message is served. A serial line is
//!   a cable on the bench and is not asked for one.
//! - **Files.** A scene named over the network (`PUT /config`, the `config` message) must be
//!   a `.toml` file inside one of the scene folders (`--scene-dir`, by default the folder of
//!   the daemon's own scene), after `..` and links are resolved; every file it names (maps,
//!   curves, the error model) too. Refusals name the path and the rule, never the content of
//!   a file that is not a scene.

use sha2::{Digest, Sha256};
use std::net::SocketAddr;
use std::path::{Component, Path, PathBuf};
use subtle::ConstantTimeEq;

/// The shortest token accepted [bytes].
pub const MIN_TOKEN_BYTES: usize = 16;

#[derive(Debug, thiserror::Error)]
pub enum AccessError {
    #[error("token file {path}: {message}")]
    TokenFile { path: String, message: String },
    #[error("scene folder {path}: {message}")]
    SceneDir { path: String, message: String },
    #[error(
        "{what} {addr} is not a loopback address and no access token is set: give \
         --token-file FILE (clients then authenticate with it), or --insecure to serve \
         anyone who can reach the port"
    )]
    OpenWithoutToken {
        what: &'static str,
        addr: SocketAddr,
    },
    #[error(
        "{what} {addr} is not a loopback address and its protocol carries no access token: \
         bind it to loopback (and reach it through a tunnel), or give --insecure"
    )]
    Tokenless {
        what: &'static str,
        addr: SocketAddr,
    },
}

/// The daemon's access rules (see the module's documentation).
#[derive(Clone, Debug, Default)]
pub struct Access {
    token_sha256: Option<[u8; 32]>,
    /// Canonical folders.
    scene_dirs: Vec<PathBuf>,
    insecure: bool,
}

impl Access {
    /// `token`: the token itself (see [`Access::read_token_file`]); `scene_dirs`: folders
    /// that must exist; `insecure`: serve non-loopback addresses without a token.
    pub fn new(
        token: Option<&str>,
        scene_dirs: &[PathBuf],
        insecure: bool,
    ) -> Result<Access, AccessError> {
        let scene_dirs = scene_dirs
            .iter()
            .map(|d| {
                let c = d.canonicalize().map_err(|e| AccessError::SceneDir {
                    path: d.display().to_string(),
                    message: e.to_string(),
                })?;
                if c.is_dir() {
                    Ok(c)
                } else {
                    Err(AccessError::SceneDir {
                        path: d.display().to_string(),
                        message: "not a folder".into(),
                    })
                }
            })
            .collect::<Result<_, _>>()?;
        Ok(Access {
            token_sha256: token.map(digest),
            scene_dirs,
            insecure,
        })
    }

    /// The token in a file: its first line, at least [`MIN_TOKEN_BYTES`] long; the file
    /// must not be readable by group or others (as ssh asks of a private key).
    pub fn read_token_file(path: &Path) -> Result<String, AccessError> {
        let bad = |message: String| AccessError::TokenFile {
            path: path.display().to_string(),
            message,
        };
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let mode = std::fs::metadata(path)
                .map_err(|e| bad(e.to_string()))?
                .permissions()
                .mode();
            if mode & 0o077 != 0 {
                return Err(bad(format!(
                    "mode {:o} lets group or others read it: chmod 600",
                    mode & 0o777
                )));
            }
        }
        let text = std::fs::read(path).map_err(|e| bad(e.to_string()))?;
        let text = String::from_utf8(text).map_err(|_| bad("not UTF-8 text".into()))?;
        let token = text.lines().next().unwrap_or("").trim().to_string();
        if token.len() < MIN_TOKEN_BYTES {
            return Err(bad(format!(
                "the token (its first line) has {} bytes; at least {MIN_TOKEN_BYTES} are needed",
                token.len()
            )));
        }
        Ok(token)
    }

    /// Refuses a non-loopback listener without a token (unless insecure).
    pub fn check_bind(&self, what: &'static str, addr: SocketAddr) -> Result<(), AccessError> {
        if addr.ip().is_loopback() || self.token_sha256.is_some() {
            return Ok(());
        }
        if self.insecure {
            tracing::warn!(
                %addr,
                what,
                "--insecure: serving a non-loopback address without an access token"
            );
            return Ok(());
        }
        Err(AccessError::OpenWithoutToken { what, addr })
    }

    /// Refuses a non-loopback listener of a protocol that carries no token (the SurRender
    /// endpoint) unless insecure: a token cannot protect it.
    pub fn check_bind_tokenless(
        &self,
        what: &'static str,
        addr: SocketAddr,
    ) -> Result<(), AccessError> {
        if addr.ip().is_loopback() || self.insecure {
            return self.check_bind(what, addr);
        }
        Err(AccessError::Tokenless { what, addr })
    }

    pub fn requires_token(&self) -> bool {
        self.token_sha256.is_some()
    }

    pub fn insecure(&self) -> bool {
        self.insecure
    }

    /// Whether `presented` is the token (always true when none is set). Constant time in
    /// the token's content and length.
    pub fn token_ok(&self, presented: Option<&str>) -> bool {
        match self.token_sha256 {
            None => true,
            Some(want) => {
                let got = digest(presented.unwrap_or(""));
                bool::from(want.ct_eq(&got)) && presented.is_some()
            }
        }
    }

    /// The `Authorization: Bearer TOKEN` header's verdict.
    pub fn bearer_ok(&self, header: Option<&str>) -> bool {
        self.token_ok(
            header
                .and_then(|h| h.strip_prefix("Bearer "))
                .map(str::trim),
        )
    }

    pub fn scene_dirs(&self) -> &[PathBuf] {
        &self.scene_dirs
    }

    /// A scene named by a client, as the file to read: a `.toml` file inside a scene folder
    /// (a relative path is taken from the first one).
    pub fn scene_path(&self, named: &str) -> Result<PathBuf, String> {
        let Some(first) = self.scene_dirs.first() else {
            return Err(format!(
                "scene {named:?}: no scene folder is configured, so scenes cannot be named over \
                 the network (start the daemon with --scene-dir DIR)"
            ));
        };
        let path = first.join(named);
        if path.extension().and_then(|e| e.to_str()) != Some("toml") {
            return Err(format!("scene {named:?}: a scene is a .toml file"));
        }
        self.allows(&path)
            .map_err(|reason| format!("scene {named:?}: {reason}"))?;
        path.canonicalize()
            .map_err(|e| format!("scene {named:?}: {e}"))
    }

    /// `Ok` when `path` lies inside a scene folder, both as written (`..` resolved) and with
    /// its links resolved.
    pub fn allows(&self, path: &Path) -> Result<(), String> {
        let outside = || {
            format!(
                "outside the scene folders ({}); the daemon reads no other file for a client",
                self.scene_dirs
                    .iter()
                    .map(|d| d.display().to_string())
                    .collect::<Vec<_>>()
                    .join(", ")
            )
        };
        let inside = |p: &Path| self.scene_dirs.iter().any(|d| p.starts_with(d));
        if !inside(&lexical(path)) {
            return Err(outside());
        }
        match path.canonicalize() {
            Ok(c) if inside(&c) => Ok(()),
            Ok(_) => Err(outside()),
            Err(e) => Err(format!("cannot be read: {e}")),
        }
    }
}

fn digest(s: &str) -> [u8; 32] {
    Sha256::digest(s.as_bytes()).into()
}

/// `path` made absolute with its `.` and `..` removed, without touching the file system.
fn lexical(path: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    let base = if path.is_absolute() {
        PathBuf::new()
    } else {
        std::env::current_dir().unwrap_or_default()
    };
    for c in base.join(path).components() {
        match c {
            Component::ParentDir => {
                out.pop();
            }
            Component::CurDir => {}
            other => out.push(other),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("optistim-access-{tag}-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn the_token_is_checked_whole() {
        let a = Access::new(Some("0123456789abcdef"), &[], false).unwrap();
        assert!(a.token_ok(Some("0123456789abcdef")));
        for bad in [
            None,
            Some(""),
            Some("0123456789abcde"),
            Some("0123456789abcdeF"),
        ] {
            assert!(!a.token_ok(bad), "{bad:?}");
        }
        assert!(a.bearer_ok(Some("Bearer 0123456789abcdef")));
        assert!(!a.bearer_ok(Some("0123456789abcdef")));
        assert!(!a.bearer_ok(None));
        assert!(Access::default().token_ok(None), "no token set: open");
    }

    #[test]
    fn open_addresses_need_a_token_or_insecure() {
        let lo: SocketAddr = "127.0.0.1:1".parse().unwrap();
        let any: SocketAddr = "0.0.0.0:1".parse().unwrap();
        assert!(Access::default().check_bind("HTTP", lo).is_ok());
        let e = Access::default().check_bind("HTTP", any).unwrap_err();
        assert!(e.to_string().contains("--token-file"), "{e}");
        assert!(
            Access::new(None, &[], true)
                .unwrap()
                .check_bind("HTTP", any)
                .is_ok()
        );
        let t = Access::new(Some("0123456789abcdef"), &[], false).unwrap();
        assert!(t.check_bind("HTTP", any).is_ok());
    }

    #[test]
    fn scenes_stay_inside_their_folders() {
        let d = temp("dirs");
        std::fs::write(d.join("a.toml"), "").unwrap();
        std::fs::write(d.join("a.txt"), "").unwrap();
        let a = Access::new(None, std::slice::from_ref(&d), false).unwrap();
        assert!(a.scene_path("a.toml").is_ok());
        assert!(a.scene_path(d.join("a.toml").to_str().unwrap()).is_ok());
        for bad in [
            "/etc/shadow",
            "../../../../etc/passwd",
            "a.txt",
            "/etc/x.toml",
        ] {
            let e = a.scene_path(bad).unwrap_err();
            assert!(!e.contains("root"), "{e}");
        }
        let e = a.scene_path("../../../../etc/x.toml").unwrap_err();
        assert!(e.contains("outside the scene folders"), "{e}");
        #[cfg(unix)]
        {
            let link = d.join("link.toml");
            let _ = std::fs::remove_file(&link);
            std::os::unix::fs::symlink("/etc/passwd", &link).unwrap();
            let e = a.scene_path("link.toml").unwrap_err();
            assert!(e.contains("outside the scene folders"), "{e}");
        }
        let none = Access::default().scene_path("a.toml").unwrap_err();
        assert!(none.contains("--scene-dir"), "{none}");
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[cfg(unix)]
    #[test]
    fn a_token_file_is_private_and_long_enough() {
        use std::os::unix::fs::PermissionsExt;
        let d = temp("token");
        let f = d.join("token");
        std::fs::write(&f, "0123456789abcdef\n").unwrap();
        std::fs::set_permissions(&f, std::fs::Permissions::from_mode(0o644)).unwrap();
        let e = Access::read_token_file(&f).unwrap_err();
        assert!(e.to_string().contains("chmod 600"), "{e}");
        std::fs::set_permissions(&f, std::fs::Permissions::from_mode(0o600)).unwrap();
        assert_eq!(Access::read_token_file(&f).unwrap(), "0123456789abcdef");
        std::fs::write(&f, "short\n").unwrap();
        assert!(Access::read_token_file(&f).is_err());
        std::fs::remove_dir_all(&d).unwrap();
    }
}
