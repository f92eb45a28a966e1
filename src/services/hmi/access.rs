//! Who may reach the screen and who may command it: the checks of every request.
//!
//! - **Host** (every request): an IP literal, `localhost`, or the host of an origin allowed with
//!   `--hmi-allow-origin`. A DNS-rebinding page reaches the port under its own domain name and
//!   is refused, so it can neither read the screen nor open its WebSocket.
//! - **Origin** (the WebSocket): a browser sends the page's origin with every WebSocket; only the
//!   screen's own origin (`http://` + the Host it was reached at) and the allowed origins may
//!   connect. Any other web page the operator has open is refused before the upgrade — a
//!   cross-site WebSocket could otherwise stop, jog and start programs from the operator's
//!   browser. A client without an Origin is not a browser page, and no other page can make the
//!   operator's browser omit it.
//! - **Token**: in the query (`?token=`, the address the operator opens), an
//!   `Authorization: Bearer` header, or the `pkm_token` cookie that the page's first load with
//!   the right token sets (HttpOnly, SameSite=Strict), compared in constant time.

use std::net::IpAddr;

use axum::http::header::{AUTHORIZATION, COOKIE, HOST, ORIGIN};
use axum::http::{HeaderMap, HeaderName};
use subtle::ConstantTimeEq;

/// The cookie that carries the token once the page was opened with it.
pub const TOKEN_COOKIE: &str = "pkm_token";

/// The shortest token accepted for a screen served beyond loopback.
pub const MIN_TOKEN_LEN: usize = 16;

/// The access rules of one screen.
#[derive(Clone, Debug, Default)]
pub struct Access {
    /// Commands need this token; `None`: every admitted client may command (loopback only).
    pub token: Option<String>,
    /// Origins besides the screen's own that may open the WebSocket (`scheme://host[:port]`,
    /// as browsers send them: lower case, no trailing slash).
    pub allowed_origins: Vec<String>,
}

impl Access {
    /// Whether a request that names `Host: host` may be served.
    pub fn host_allowed(&self, headers: &HeaderMap) -> bool {
        let Some(host) = header_text(headers, HOST) else {
            // HTTP/1.1 requires Host; a request without one is not a browser's.
            return false;
        };
        let name = host_name(host);
        if name.eq_ignore_ascii_case("localhost") || name.parse::<IpAddr>().is_ok() {
            return true;
        }
        self.allowed_origins
            .iter()
            .any(|o| host_name(o.split_once("://").map_or(o.as_str(), |(_, h)| h)).eq_ignore_ascii_case(name))
    }

    /// Whether a WebSocket upgrade with these headers may connect: no `Origin` (not a browser
    /// page), the page's own origin (the Host it reached), or an allowed one.
    pub fn origin_allowed(&self, headers: &HeaderMap) -> bool {
        let Some(origin) = headers.get(ORIGIN) else {
            return true;
        };
        let Ok(origin) = origin.to_str() else {
            return false;
        };
        let host = header_text(headers, HOST).unwrap_or("");
        let own = ["http://", "https://"].iter().any(|scheme| {
            origin
                .strip_prefix(scheme)
                .is_some_and(|h| h.eq_ignore_ascii_case(host))
        });
        own || self.allowed_origins.iter().any(|o| o.eq_ignore_ascii_case(origin))
    }

    /// Whether the request carries the token (query `query_token`, the bearer header, or the
    /// cookie); true when no token is set.
    pub fn may_command(&self, query_token: Option<&str>, headers: &HeaderMap) -> bool {
        self.credentials(query_token, headers) == Credentials::Command
    }

    /// What the request's tokens (query `query_token`, the bearer header, the cookie) are
    /// worth: commands with the right one (or when no token is set), watching without any, a
    /// guess with only wrong ones.
    pub fn credentials(&self, query_token: Option<&str>, headers: &HeaderMap) -> Credentials {
        let Some(token) = &self.token else {
            return Credentials::Command;
        };
        let bearer = header_text(headers, AUTHORIZATION).and_then(|h| h.strip_prefix("Bearer "));
        let cookie = cookie(headers, TOKEN_COOKIE);
        let given: Vec<&str> = [query_token, bearer, cookie.as_deref()].into_iter().flatten().collect();
        if given.iter().any(|candidate| same(candidate, token)) {
            Credentials::Command
        } else if given.is_empty() {
            Credentials::Watch
        } else {
            Credentials::Wrong
        }
    }

    /// The `Set-Cookie` value that keeps the token for the page's WebSocket, if `query_token` is
    /// the right one (a wrong token sets nothing).
    pub fn token_cookie(&self, query_token: Option<&str>) -> Option<String> {
        let token = self.token.as_deref()?;
        let given = query_token?;
        same(given, token).then(|| format!("{TOKEN_COOKIE}={token}; Path=/; HttpOnly; SameSite=Strict"))
    }
}

/// What a request's tokens are worth.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Credentials {
    /// The right token, or none is needed: the client may command.
    Command,
    /// No token: the client watches.
    Watch,
    /// Only wrong tokens: the client watches, and the guess is answered after the source's
    /// back-off.
    Wrong,
}

/// The text of header `name`; `None` when it is absent or not visible ASCII.
pub fn header_text(headers: &HeaderMap, name: HeaderName) -> Option<&str> {
    headers.get(name).and_then(|h| h.to_str().ok())
}

/// Whether `a` and `b` are the same token, in time that does not depend on where they differ.
fn same(a: &str, b: &str) -> bool {
    a.len() == b.len() && bool::from(a.as_bytes().ct_eq(b.as_bytes()))
}

/// The host name of `host[:port]` (an IPv6 literal keeps its brackets off: `[::1]:80` → `::1`).
fn host_name(host: &str) -> &str {
    if let Some(rest) = host.strip_prefix('[') {
        return rest.split(']').next().unwrap_or(rest);
    }
    host.rsplit_once(':')
        .filter(|(_, port)| port.bytes().all(|b| b.is_ascii_digit()))
        .map_or(host, |(name, _)| name)
}

/// The value of cookie `name` in the request's `Cookie` headers.
fn cookie(headers: &HeaderMap, name: &str) -> Option<String> {
    headers
        .get_all(COOKIE)
        .iter()
        .filter_map(|h| h.to_str().ok())
        .flat_map(|h| h.split(';'))
        .filter_map(|pair| pair.trim().split_once('='))
        .find(|(k, _)| *k == name)
        .map(|(_, v)| v.to_string())
}

/// A token is acceptable for `addr`: not empty, of printable ASCII without spaces (it travels
/// in URLs, headers and cookies), and beyond loopback at least [`MIN_TOKEN_LEN`] characters.
pub fn check_token(token: &str, loopback: bool) -> Result<(), String> {
    if token.is_empty() {
        return Err("the token is empty".into());
    }
    if !token
        .bytes()
        .all(|b| b.is_ascii_graphic() && !matches!(b, b';' | b',' | b'"' | b'\\'))
    {
        return Err("the token must be printable ASCII without spaces, ';', ',', '\"' or '\\'".into());
    }
    if !loopback && token.len() < MIN_TOKEN_LEN {
        return Err(format!(
            "a token for a screen served beyond this computer needs at least {MIN_TOKEN_LEN} characters, got {}",
            token.len()
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use axum::http::HeaderValue;

    fn headers(pairs: &[(&'static str, &str)]) -> HeaderMap {
        let mut h = HeaderMap::new();
        for (k, v) in pairs {
            h.append(*k, HeaderValue::from_str(v).expect("a header value"));
        }
        h
    }

    #[test]
    fn only_ip_literals_localhost_and_allowed_hosts_are_served() {
        let access = Access {
            token: None,
            allowed_origins: vec!["https://plc.lab.example".into()],
        };
        for ok in [
            "127.0.0.1:8080",
            "localhost:8080",
            "[::1]:8080",
            "192.168.1.10",
            "plc.lab.example:443",
        ] {
            assert!(access.host_allowed(&headers(&[("host", ok)])), "{ok}");
        }
        for refused in ["evil.example:8080", "127.0.0.1.evil.example", "localhost.evil:8080"] {
            assert!(!access.host_allowed(&headers(&[("host", refused)])), "{refused}");
        }
        assert!(!access.host_allowed(&HeaderMap::new()), "no Host");
    }

    #[test]
    fn a_websocket_from_another_origin_is_refused() {
        let access = Access {
            token: None,
            allowed_origins: vec!["https://hmi.lab.example".into()],
        };
        let ws = |origin: Option<&str>| {
            let mut pairs = vec![("host", "127.0.0.1:8080")];
            if let Some(o) = origin {
                pairs.push(("origin", o));
            }
            access.origin_allowed(&headers(&pairs))
        };
        assert!(ws(None), "not a browser page");
        assert!(ws(Some("http://127.0.0.1:8080")), "the screen's own page");
        assert!(ws(Some("https://hmi.lab.example")), "an allowed origin");
        assert!(!ws(Some("http://127.0.0.1:9999")), "another port is another origin");
        assert!(!ws(Some("http://evil.example")));
        assert!(!ws(Some("null")), "a sandboxed frame or a file");
    }

    #[test]
    fn the_token_counts_in_the_query_a_bearer_header_or_the_cookie() {
        let access = Access {
            token: Some("0123456789abcdef".into()),
            allowed_origins: Vec::new(),
        };
        let none = HeaderMap::new();
        assert!(access.may_command(Some("0123456789abcdef"), &none));
        assert!(!access.may_command(Some("0123456789abcdeF"), &none));
        assert!(!access.may_command(Some("0123456789abcde"), &none));
        assert!(!access.may_command(None, &none));
        assert!(access.may_command(None, &headers(&[("authorization", "Bearer 0123456789abcdef")])));
        assert!(access.may_command(None, &headers(&[("cookie", "theme=dark; pkm_token=0123456789abcdef")])));
        assert!(!access.may_command(None, &headers(&[("cookie", "pkm_token=wrong")])));
        assert_eq!(
            access.token_cookie(Some("0123456789abcdef")).as_deref(),
            Some("pkm_token=0123456789abcdef; Path=/; HttpOnly; SameSite=Strict")
        );
        assert_eq!(access.token_cookie(Some("guess")), None);
        assert!(
            Access::default().may_command(None, &none),
            "no token set: loopback, all may"
        );
    }

    #[test]
    fn tokens_beyond_loopback_are_long_and_printable() {
        assert!(check_token("short", true).is_ok());
        assert!(check_token("short", false).is_err_and(|e| e.contains("at least 16 characters, got 5")));
        assert!(check_token("0123456789abcdef", false).is_ok());
        assert!(check_token("with space 12345678", false).is_err());
        assert!(check_token("", true).is_err());
    }
}
