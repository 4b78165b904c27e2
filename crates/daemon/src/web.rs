//! The daemon's web page at `/`: devices, a capture from a material preset followed live,
//! cancel and resume, and the sessions with their reports; and `/viewer.html`, a session's
//! export in 3D. Its files, three.js among them, are compiled in, so the pages work with no
//! network. It talks to the API like any client.
//!
//! With a token configured, the browser signs in once (`POST /login`, a form) and keeps the
//! token in a cookie: an address never holds it, and `EventSource`, which cannot send an
//! `Authorization` header, is let in by the cookie. The cookie is `HttpOnly`, so no script
//! reads it, and `SameSite=Strict`, so another site's request carries none. A page on another
//! port of the same host is the same site, though: what keeps such a page from acting through
//! the cookie is the API's JSON-only POSTs and its never answering CORS (see
//! `require_json_posts` in [`super::api`]).

use axum::body::Bytes;
use axum::extract::{Path, State};
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::response::{Html, IntoResponse, Redirect, Response};

use super::api::Shared;

const INDEX: &str = include_str!("web/index.html");
const SCRIPT: &str = include_str!("web/app.js");
const STYLE: &str = include_str!("web/app.css");
const VIEWER: &str = include_str!("web/viewer.html");
const VIEWER_SCRIPT: &str = include_str!("web/viewer.js");

/// three.js 0.166.1 (MIT) and the add-ons the viewer imports, as `scripts/vendor-three.sh`
/// fetched them from npm. A fixed list: a name from a request never reaches a file system.
const THREE: [(&str, &str); 5] = [
    (
        "three.module.min.js",
        include_str!("web/vendor/three/three.module.min.js"),
    ),
    (
        "GLTFLoader.js",
        include_str!("web/vendor/three/GLTFLoader.js"),
    ),
    (
        "RGBELoader.js",
        include_str!("web/vendor/three/RGBELoader.js"),
    ),
    (
        "OrbitControls.js",
        include_str!("web/vendor/three/OrbitControls.js"),
    ),
    (
        "BufferGeometryUtils.js",
        include_str!("web/vendor/three/BufferGeometryUtils.js"),
    ),
];

/// The cookie that carries the token, hex-encoded (a token may hold any character).
pub const COOKIE: &str = "brdfd_token";
/// The page may load only its own files and talk only to its own daemon.
const PAGE_POLICY: &str = "default-src 'none'; script-src 'self'; style-src 'self'; \
     connect-src 'self'; img-src 'self' data:; form-action 'self'; frame-ancestors 'none'; \
     base-uri 'none'";
/// The viewer's policy: the page's, and `data:` fetches, which is how three.js's glTF loader
/// reads the buffer the export embeds.
const VIEWER_POLICY: &str = "default-src 'none'; script-src 'self'; style-src 'self'; \
     connect-src 'self' data:; img-src 'self' data:; form-action 'self'; frame-ancestors 'none'; \
     base-uri 'none'";
/// The longest login form read: a token and its field name.
pub const MAX_LOGIN_BYTES: usize = 4096;

fn page(kind: &'static str, body: &'static str) -> Response {
    with_policy(kind, body, PAGE_POLICY)
}

fn with_policy(kind: &'static str, body: impl IntoResponse, policy: &'static str) -> Response {
    (
        [
            (header::CONTENT_TYPE, HeaderValue::from_static(kind)),
            (
                header::CONTENT_SECURITY_POLICY,
                HeaderValue::from_static(policy),
            ),
            (
                header::X_CONTENT_TYPE_OPTIONS,
                HeaderValue::from_static("nosniff"),
            ),
        ],
        body,
    )
        .into_response()
}

pub async fn index() -> Response {
    page("text/html; charset=utf-8", INDEX)
}

pub async fn script() -> Response {
    page("text/javascript; charset=utf-8", SCRIPT)
}

pub async fn style() -> Response {
    page("text/css; charset=utf-8", STYLE)
}

/// `/viewer.html?session=ID`: a session's export in 3D (`web/viewer.js` says what it shows).
pub async fn viewer() -> Response {
    with_policy("text/html; charset=utf-8", VIEWER, VIEWER_POLICY)
}

pub async fn viewer_script() -> Response {
    page("text/javascript; charset=utf-8", VIEWER_SCRIPT)
}

/// `/vendor/three/{file}`: the 3D library, compiled in so that an offline bench has it.
pub async fn three(Path(file): Path<String>) -> Response {
    match THREE.iter().find(|(name, _)| *name == file) {
        Some((_, body)) => page("text/javascript; charset=utf-8", body),
        None => (StatusCode::NOT_FOUND, "no such file").into_response(),
    }
}

/// `/maps`: the reference maps' names, in order, as JSON.
pub async fn map_names() -> Response {
    let names = serde_json::to_string(&brdfd_report::export::maps::reference_map_names())
        .expect("names serialise");
    with_policy("application/json", names, PAGE_POLICY)
}

/// `/maps/{name}.hdr`: the reference maps exports are checked under, as Radiance RGBE, for
/// the viewer to light with. They are part of brdfd, not of any session.
pub async fn map(Path(file): Path<String>) -> Response {
    let bytes = file
        .strip_suffix(".hdr")
        .and_then(brdfd_report::export::maps::reference_map_file);
    match bytes {
        Some(b) => with_policy("image/vnd.radiance", b, PAGE_POLICY),
        None => (StatusCode::NOT_FOUND, "no such map").into_response(),
    }
}

/// `POST /login` with the form field `token`: a matching token sets the cookie and returns to
/// the page; another gets 401 and a line saying so.
pub async fn login(
    State(d): State<Shared>,
    extensions: axum::http::Extensions,
    body: Bytes,
) -> Response {
    let Some(token) = &d.token else {
        // No token configured: nothing to sign in to.
        return Redirect::to("/").into_response();
    };
    let ip = super::api::peer_ip(&extensions);
    if let Some(Err(wait)) = ip.map(|ip| d.throttle.check(ip)) {
        return super::api::locked_out(wait);
    }
    let given = form_field(&body, "token").unwrap_or_default();
    let ok = same_secret(given.as_bytes(), token.as_bytes());
    if let Some(ip) = ip {
        if ok {
            d.throttle.succeeded(ip);
        } else {
            d.throttle.failed(ip);
        }
    }
    if !ok {
        return (
            StatusCode::UNAUTHORIZED,
            Html(
                "<!DOCTYPE html><title>brdfd</title><p>That is not this daemon's token (the \
                  <code>token</code> in its brdfd.toml). <a href=\"/\">Try again</a>.</p>",
            ),
        )
            .into_response();
    }
    let cookie = format!(
        "{COOKIE}={}; HttpOnly; SameSite=Strict; Path=/",
        hex(token.as_bytes())
    );
    let mut response = Redirect::to("/").into_response();
    if let Ok(v) = HeaderValue::from_str(&cookie) {
        response.headers_mut().insert(header::SET_COOKIE, v);
    }
    response
}

/// The token a request's cookie carries, if any.
pub fn token_from_cookie(headers: &HeaderMap) -> Option<Vec<u8>> {
    headers
        .get_all(header::COOKIE)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(';'))
        .filter_map(|pair| pair.trim().split_once('='))
        .find(|(name, _)| *name == COOKIE)
        .and_then(|(_, value)| unhex(value))
}

/// Compares two secrets in full, whatever the first difference: no early exit that times
/// the match.
pub fn same_secret(given: &[u8], secret: &[u8]) -> bool {
    given.len() == secret.len()
        && given
            .iter()
            .zip(secret)
            .fold(0u8, |acc, (a, b)| acc | (a ^ b))
            == 0
}

/// A field of an `application/x-www-form-urlencoded` body, decoded.
fn form_field(body: &[u8], name: &str) -> Option<String> {
    let text = std::str::from_utf8(body).ok()?;
    text.split('&').find_map(|pair| {
        let (k, v) = pair.split_once('=').unwrap_or((pair, ""));
        (percent_decode(k)? == name)
            .then(|| percent_decode(v))
            .flatten()
    })
}

/// Form decoding: `+` is a space, `%XX` a byte; the result must be UTF-8.
fn percent_decode(s: &str) -> Option<String> {
    let mut out = Vec::with_capacity(s.len());
    let mut bytes = s.bytes();
    while let Some(b) = bytes.next() {
        match b {
            b'+' => out.push(b' '),
            b'%' => {
                let hi = (bytes.next()? as char).to_digit(16)?;
                let lo = (bytes.next()? as char).to_digit(16)?;
                out.push((hi * 16 + lo) as u8);
            }
            b => out.push(b),
        }
    }
    String::from_utf8(out).ok()
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

fn unhex(s: &str) -> Option<Vec<u8>> {
    if !s.len().is_multiple_of(2) {
        return None;
    }
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(s.get(i..i + 2)?, 16).ok())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_form_token_is_decoded_and_the_cookie_round_trips() {
        assert_eq!(
            form_field(b"x=1&token=a%2Bb+c%3D", "token").as_deref(),
            Some("a+b c=")
        );
        assert_eq!(form_field(b"token=%zz", "token"), None);
        let mut headers = HeaderMap::new();
        let token = "s3cret; with=odd \"chars\"";
        headers.insert(
            header::COOKIE,
            HeaderValue::from_str(&format!("other=1; {COOKIE}={}", hex(token.as_bytes()))).unwrap(),
        );
        assert_eq!(token_from_cookie(&headers).unwrap(), token.as_bytes());
        assert!(same_secret(b"abc", b"abc"));
        assert!(!same_secret(b"abd", b"abc"));
        assert!(!same_secret(b"ab", b"abc"));
    }
}
