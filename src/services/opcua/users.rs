//! Who may command over OPC UA: the users file (`--opcua-users FILE`).
//!
//! ```json
//! { "users": [
//!     { "name": "operator", "password": "a-long-passphrase" },
//!     { "name": "cell-7", "certificate": "cell-7.der" }
//! ] }
//! ```
//!
//! A user logs in with a user name and password, or presents the certificate (X.509 identity
//! token, DER or PEM; a relative path is taken from the users file's directory). The file is
//! read strictly (an unknown key, a duplicate name, a user with both or neither is an error that
//! names the file and the place in it); a file holding passwords must not be readable by others
//! (`chmod 600`), as ssh requires of a private key.

use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};

use serde::Deserialize;
use subtle::ConstantTimeEq;

use opcua::crypto::Thumbprint;

/// The shortest password accepted.
pub const MIN_PASSWORD_LEN: usize = 8;

/// The most users a file may list.
pub const MAX_USERS: usize = 256;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct UsersFile {
    users: Vec<UserEntry>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct UserEntry {
    name: String,
    #[serde(default)]
    password: Option<String>,
    #[serde(default)]
    certificate: Option<PathBuf>,
}

/// How a user proves who they are.
#[derive(Clone)]
pub enum Credential {
    /// A password.
    Password(String),
    /// An X.509 certificate (its thumbprint, and the file it came from).
    Certificate {
        /// The certificate's SHA-1 thumbprint, as OPC UA identifies a certificate.
        thumbprint: Thumbprint,
        /// The certificate file.
        path: PathBuf,
    },
}

impl std::fmt::Debug for Credential {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Credential::Password(_) => f.write_str("Password(****)"),
            Credential::Certificate { path, .. } => write!(f, "Certificate({})", path.display()),
        }
    }
}

/// One user who may command.
#[derive(Clone, Debug)]
pub struct User {
    /// The user's name (in the log of what they did).
    pub name: String,
    /// How they log in.
    pub credential: Credential,
}

/// The users who may command.
#[derive(Clone, Debug, Default)]
pub struct Users {
    /// In the file's order.
    pub users: Vec<User>,
    /// The file they came from.
    pub origin: PathBuf,
}

impl Users {
    /// Reads the users file at `path`.
    pub fn load(path: &Path) -> Result<Users, String> {
        let at = |e: String| format!("{}: {e}", path.display());
        let text = crate::runtime::files::read_text(path, 1 << 20).map_err(|e| at(e.to_string()))?;
        let crate::strict_json::Unique(value) = serde_json::from_str(&text).map_err(|e| at(e.to_string()))?;
        let file: UsersFile = crate::strict_json::from_value(&value).map_err(|e| {
            let place = e.path().to_string();
            at(format!("{place}: {}", e.into_inner()))
        })?;
        let dir = path.parent().unwrap_or(Path::new("."));
        let users = Users::from_entries(file.users, dir).map_err(at)?;
        if users.has_passwords() {
            let mode = std::fs::metadata(path)
                .map_err(|e| at(e.to_string()))?
                .permissions()
                .mode();
            if mode & 0o077 != 0 {
                return Err(at(format!(
                    "it holds passwords and others may read it (mode {:o}): chmod 600 {}",
                    mode & 0o777,
                    path.display()
                )));
            }
        }
        Ok(Users {
            origin: path.to_path_buf(),
            ..users
        })
    }

    fn from_entries(entries: Vec<UserEntry>, dir: &Path) -> Result<Users, String> {
        if entries.is_empty() {
            return Err("users: the list is empty (no one could command)".into());
        }
        if entries.len() > MAX_USERS {
            return Err(format!("users: {} users, at most {MAX_USERS}", entries.len()));
        }
        let mut users: Vec<User> = Vec::with_capacity(entries.len());
        for (k, entry) in entries.into_iter().enumerate() {
            let place = format!("users[{k}]");
            let name = entry.name;
            if name.is_empty() || name.len() > 64 || !name.chars().all(|c| c.is_ascii_graphic()) {
                return Err(format!(
                    "{place}.name: a user name is 1 … 64 printable characters without spaces, got \"{}\"",
                    crate::runtime::config::shorten(&name)
                ));
            }
            if users.iter().any(|u| u.name == name) {
                return Err(format!("{place}.name: \"{name}\" is listed twice"));
            }
            let credential = match (entry.password, entry.certificate) {
                (Some(p), None) => {
                    if p.chars().count() < MIN_PASSWORD_LEN {
                        return Err(format!(
                            "{place}.password: at least {MIN_PASSWORD_LEN} characters, got {}",
                            p.chars().count()
                        ));
                    }
                    Credential::Password(p)
                }
                (None, Some(c)) => {
                    let path = if c.is_absolute() { c } else { dir.join(c) };
                    let cert =
                        read_certificate(&path).map_err(|e| format!("{place}.certificate: {}: {e}", path.display()))?;
                    Credential::Certificate {
                        thumbprint: cert.thumbprint(),
                        path,
                    }
                }
                (Some(_), Some(_)) => {
                    return Err(format!("{place}: a password or a certificate, not both"));
                }
                (None, None) => return Err(format!("{place}: needs a password or a certificate")),
            };
            users.push(User { name, credential });
        }
        Ok(Users {
            users,
            origin: PathBuf::new(),
        })
    }

    /// Whether any user logs in with a password.
    pub fn has_passwords(&self) -> bool {
        self.users
            .iter()
            .any(|u| matches!(u.credential, Credential::Password(_)))
    }

    /// Whether any user logs in with a certificate.
    pub fn has_certificates(&self) -> bool {
        self.users
            .iter()
            .any(|u| matches!(u.credential, Credential::Certificate { .. }))
    }

    /// The user with this name and password. Every password is compared, in constant time, so
    /// the time taken tells nothing of which names exist or how much of a password was right.
    pub fn check_password(&self, name: &str, password: &str) -> Option<&User> {
        let mut found = None;
        for user in &self.users {
            if let Credential::Password(p) = &user.credential {
                let same_name = user.name.as_bytes().ct_eq(name.as_bytes());
                let same_password = p.as_bytes().ct_eq(password.as_bytes());
                if bool::from(same_name & same_password) {
                    found = Some(user);
                }
            }
        }
        found
    }

    /// The user whose certificate has this thumbprint.
    pub fn check_certificate(&self, thumbprint: &Thumbprint) -> Option<&User> {
        self.users.iter().find(|u| match &u.credential {
            Credential::Certificate { thumbprint: t, .. } => t.value() == thumbprint.value(),
            Credential::Password(_) => false,
        })
    }
}

/// A certificate from a DER or PEM file.
pub fn read_certificate(path: &Path) -> Result<opcua::crypto::X509, String> {
    let file = crate::runtime::files::open_regular(path).map_err(|e| e.to_string())?;
    let bytes = crate::runtime::files::read_to_limit(file, 1 << 20).map_err(|e| e.to_string())?;
    let parsed = if bytes.starts_with(b"-----BEGIN") {
        opcua::crypto::X509::from_pem(&bytes)
    } else {
        opcua::crypto::X509::from_der(&bytes)
    };
    parsed.map_err(|e| format!("not an X.509 certificate in DER or PEM ({e})"))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, text: &str, mode: u32) -> PathBuf {
        let path = dir.join("users.json");
        std::fs::write(&path, text).expect("write");
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(mode)).expect("chmod");
        path
    }

    #[test]
    fn a_users_file_is_read_strictly_and_names_the_place_of_a_problem() {
        let dir = tempfile::tempdir().expect("tempdir");
        let ok = write(
            dir.path(),
            r#"{"users": [{"name": "operator", "password": "a-long-passphrase"}]}"#,
            0o600,
        );
        let users = Users::load(&ok).expect("valid");
        assert_eq!(users.users.len(), 1);
        assert!(users.check_password("operator", "a-long-passphrase").is_some());
        assert!(users.check_password("operator", "a-long-passphrasE").is_none());
        assert!(users.check_password("operato", "a-long-passphrase").is_none());

        let cases = [
            (
                r#"{"users": [{"name": "op", "pasword": "a-long-passphrase"}]}"#,
                "users[0].pasword: unknown field `pasword`, expected one of `name`, `password`, `certificate`",
            ),
            (
                r#"{"users": [{"name": "op", "password": "short"}]}"#,
                "users[0].password: at least 8 characters, got 5",
            ),
            (
                r#"{"users": [{"name": "op", "password": "a-long-passphrase"}, {"name": "op", "password": "another-passphrase"}]}"#,
                "users[1].name: \"op\" is listed twice",
            ),
            (
                r#"{"users": [{"name": "op"}]}"#,
                "users[0]: needs a password or a certificate",
            ),
            (
                r#"{"users": [{"name": "o p", "password": "a-long-passphrase"}]}"#,
                "users[0].name: a user name is 1 … 64 printable characters without spaces, got \"o p\"",
            ),
            (r#"{"users": []}"#, "users: the list is empty (no one could command)"),
            (
                r#"{"users": [{"name": "op", "certificate": "missing.der"}]}"#,
                "users[0].certificate: ",
            ),
        ];
        for (text, expected) in cases {
            let path = write(dir.path(), text, 0o600);
            let e = Users::load(&path).expect_err("refused");
            assert!(e.starts_with(&format!("{}: {expected}", path.display())), "{text}: {e}");
        }
    }

    #[test]
    fn a_password_file_others_may_read_is_refused() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = write(
            dir.path(),
            r#"{"users": [{"name": "operator", "password": "a-long-passphrase"}]}"#,
            0o644,
        );
        assert_eq!(
            Users::load(&path).err(),
            Some(format!(
                "{0}: it holds passwords and others may read it (mode 644): chmod 600 {0}",
                path.display()
            ))
        );
    }
}
