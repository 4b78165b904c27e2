//! The camera's side of HTTP Digest (RFC 7616 with MD5 and qop=auth), as a THETA in client
//! mode checks it. Written here from the RFC, apart from the client's crate, so that the
//! client's answers are checked by an independent implementation.

use std::collections::BTreeMap;

use md5::{Digest, Md5};

fn md5_hex(s: &str) -> String {
    Md5::digest(s.as_bytes())
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// The fields of an `Authorization: Digest ...` header: `key=value` or `key="value"`, comma
/// separated; quoted values may hold commas.
pub fn parse_authorization(header: &str) -> Option<BTreeMap<String, String>> {
    let rest = header.trim().strip_prefix("Digest")?.trim_start();
    let mut out = BTreeMap::new();
    let mut chars = rest.chars().peekable();
    loop {
        while matches!(chars.peek(), Some(c) if *c == ',' || c.is_whitespace()) {
            chars.next();
        }
        let key: String = chars.by_ref().take_while(|&c| c != '=').collect();
        if key.is_empty() {
            break;
        }
        let value = if chars.peek() == Some(&'"') {
            chars.next();
            let mut v = String::new();
            while let Some(c) = chars.next() {
                match c {
                    '\\' => v.extend(chars.next()),
                    '"' => break,
                    c => v.push(c),
                }
            }
            v
        } else {
            chars.by_ref().take_while(|&c| c != ',').collect::<String>()
        };
        out.insert(key.trim().to_ascii_lowercase(), value.trim().to_string());
    }
    Some(out)
}

/// Whether `fields` (a parsed Authorization header) answer the challenge `nonce` for this
/// request. `realm`, user and password are the camera's.
pub fn verify(
    fields: &BTreeMap<String, String>,
    method: &str,
    uri: &str,
    realm: &str,
    user: &str,
    password: &str,
    nonce: &str,
) -> Result<(), &'static str> {
    let get = |k: &str| fields.get(k).map(String::as_str);
    if get("username") != Some(user) {
        return Err("unknown user");
    }
    if get("realm") != Some(realm) || get("nonce") != Some(nonce) {
        return Err("stale or foreign nonce");
    }
    if get("uri") != Some(uri) {
        return Err("uri does not match the request");
    }
    if get("qop") != Some("auth") {
        return Err("qop must be auth");
    }
    let (Some(nc), Some(cnonce), Some(response)) = (get("nc"), get("cnonce"), get("response"))
    else {
        return Err("nc, cnonce or response missing");
    };
    let ha1 = md5_hex(&format!("{user}:{realm}:{password}"));
    let ha2 = md5_hex(&format!("{method}:{uri}"));
    let expected = md5_hex(&format!("{ha1}:{nonce}:{nc}:{cnonce}:auth:{ha2}"));
    if expected == response {
        Ok(())
    } else {
        Err("wrong response (password)")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// RFC 7616 section 3.9.1's MD5 example, with qop=auth.
    #[test]
    fn rfc7616_example_verifies() {
        let h = r#"Digest username="Mufasa", realm="http-auth@example.org", uri="/dir/index.html", algorithm=MD5, nonce="7ypf/xlj9XXwfDPEoM4URrv/xwf94BcCAzFZH4GiTo0v", nc=00000001, cnonce="f2/wE4q74E6zIJEtWaHKaf5wv/H5QzzpXusqGemxURZJ", qop=auth, response="8ca523f5e9506fed4657c9700eebdbec", opaque="FQhe/qaU925kfnzjCev0ciny7QMkPqMAFRtzCUYo5tdS""#;
        let f = parse_authorization(h).unwrap();
        assert_eq!(f["cnonce"], "f2/wE4q74E6zIJEtWaHKaf5wv/H5QzzpXusqGemxURZJ");
        let ok = verify(
            &f,
            "GET",
            "/dir/index.html",
            "http-auth@example.org",
            "Mufasa",
            "Circle of Life",
            "7ypf/xlj9XXwfDPEoM4URrv/xwf94BcCAzFZH4GiTo0v",
        );
        assert_eq!(ok, Ok(()));
        let bad = verify(
            &f,
            "GET",
            "/dir/index.html",
            "http-auth@example.org",
            "Mufasa",
            "wrong",
            "7ypf/xlj9XXwfDPEoM4URrv/xwf94BcCAzFZH4GiTo0v",
        );
        assert!(bad.is_err());
    }
}
