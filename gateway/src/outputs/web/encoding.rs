//! Compression and validators of the page's answers.
//!
//! - **gzip by `Accept-Encoding`** ([`compress`]): HTML, script, style sheets, SVG and
//!   JSON of a known length from 256 bytes up are sent gzipped to a client that
//!   accepts it (with `Vary: Accept-Encoding`); the live-update stream
//!   (`text/event-stream`) and binary downloads are sent as they are. No brotli: it
//!   would be a second codec crate for a few per cent on answers this size.
//! - **Validators on the assets** ([`Asset`]): each compiled-in asset has a strong
//!   `ETag` from the hash of its bytes (the gzipped form its own, with `-gzip`), and
//!   `If-None-Match` on it is answered 304. The pages and the API carry no validator:
//!   the pages are `no-cache` (they are small), the API's live figures `no-store`.

use std::hash::{Hash, Hasher};
use std::io::Write as _;

use axum::body::{Body, Bytes, HttpBody as _};
use axum::extract::Request;
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};

/// Answers shorter than this, bytes, are sent as they are (gzip's frame would eat
/// what it saves).
const MIN_BYTES: u64 = 256;
/// Answers longer than this, bytes, are sent as they are (none of the API's is: a
/// capture's JSON is a few MB).
const MAX_BYTES: u64 = 64 << 20;
/// Answers longer than this, bytes, are compressed on the blocking pool, not on the
/// server's task.
const BLOCKING_BYTES: u64 = 64 << 10;

/// Whether `headers`' `Accept-Encoding` accepts gzip (RFC 9110 §12.5.3): `gzip` (or
/// `x-gzip`) with a q-value above 0, or `*` above 0 when gzip is not listed.
pub(crate) fn accepts_gzip(headers: &HeaderMap) -> bool {
    let mut star = false;
    for value in headers.get_all(header::ACCEPT_ENCODING) {
        let Ok(value) = value.to_str() else { continue };
        for item in value.split(',') {
            let mut parts = item.split(';');
            let coding = parts.next().unwrap_or("").trim().to_ascii_lowercase();
            let weight = parts
                .filter_map(|parameter| {
                    let (name, value) = parameter.split_once('=')?;
                    name.trim()
                        .eq_ignore_ascii_case("q")
                        .then(|| value.trim().parse::<f32>().ok())?
                })
                .next()
                .unwrap_or(1.0);
            match coding.as_str() {
                "gzip" | "x-gzip" => return weight > 0.0,
                "*" => star = weight > 0.0,
                _ => {}
            }
        }
    }
    star
}

/// Whether an answer of `content_type` is worth compressing (text, not a stream).
fn compressible(content_type: &str) -> bool {
    let essence = content_type.split(';').next().unwrap_or("").trim();
    matches!(
        essence,
        "text/html" | "text/css" | "text/javascript" | "application/json" | "image/svg+xml"
    )
}

/// `bytes` gzipped (level 6).
fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut encoder = flate2::write::GzEncoder::new(
        Vec::with_capacity(bytes.len() / 3),
        flate2::Compression::default(),
    );
    // Writing into a Vec does not fail.
    let _ = encoder.write_all(bytes);
    encoder.finish().unwrap_or_default()
}

/// Middleware: gzips a compressible answer of a known length when the request
/// accepts gzip, and marks every compressible answer `Vary: Accept-Encoding`.
pub(crate) async fn compress(request: Request, next: Next) -> Response {
    let gzip_accepted = accepts_gzip(request.headers());
    let response = next.run(request).await;
    let headers = response.headers();
    if !headers
        .get(header::CONTENT_TYPE)
        .and_then(|value| value.to_str().ok())
        .is_some_and(compressible)
    {
        return response;
    }
    let (mut parts, body) = response.into_parts();
    if !parts.headers.contains_key(header::VARY) {
        parts.headers.insert(
            header::VARY,
            HeaderValue::from_static(header::ACCEPT_ENCODING.as_str()),
        );
    }
    let length = body.size_hint().exact();
    let worth = parts.status == StatusCode::OK
        && gzip_accepted
        && !parts.headers.contains_key(header::CONTENT_ENCODING)
        && length.is_some_and(|length| (MIN_BYTES..=MAX_BYTES).contains(&length));
    if !worth {
        return Response::from_parts(parts, body);
    }
    let Ok(bytes) =
        axum::body::to_bytes(body, usize::try_from(MAX_BYTES).unwrap_or(usize::MAX)).await
    else {
        return crate::outputs::http::error(
            StatusCode::INTERNAL_SERVER_ERROR,
            "the answer could not be read",
        );
    };
    let compressed = if length.unwrap_or(0) > BLOCKING_BYTES {
        match tokio::task::spawn_blocking(move || gzip(&bytes)).await {
            Ok(compressed) => compressed,
            Err(_) => {
                return crate::outputs::http::error(
                    StatusCode::INTERNAL_SERVER_ERROR,
                    "the answer could not be compressed",
                )
            }
        }
    } else {
        gzip(&bytes)
    };
    parts
        .headers
        .insert(header::CONTENT_ENCODING, HeaderValue::from_static("gzip"));
    parts.headers.remove(header::CONTENT_LENGTH);
    Response::from_parts(parts, Body::from(compressed))
}

/// A compiled-in asset in the forms it is sent in, with their validators.
#[derive(Debug)]
pub(crate) struct Asset {
    /// Its path under `/assets/`.
    pub(crate) name: &'static str,
    content_type: &'static str,
    cache_control: &'static str,
    identity: &'static [u8],
    /// The gzipped bytes, for a compressible type.
    gzipped: Option<Bytes>,
    /// Strong ETag of the bytes as they are (quoted).
    etag: String,
    /// Strong ETag of the gzipped bytes (quoted).
    etag_gzip: String,
}

impl Asset {
    /// `bytes` served as `content_type` with `cache_control`.
    pub(crate) fn new(
        name: &'static str,
        content_type: &'static str,
        bytes: &'static [u8],
        cache_control: &'static str,
    ) -> Self {
        // SipHash with fixed keys: the same bytes give the same tag in this build.
        let mut hasher = std::hash::DefaultHasher::new();
        bytes.hash(&mut hasher);
        let hash = hasher.finish();
        Self {
            name,
            content_type,
            cache_control,
            identity: bytes,
            gzipped: compressible(content_type).then(|| Bytes::from(gzip(bytes))),
            etag: format!("\"{hash:016x}\""),
            etag_gzip: format!("\"{hash:016x}-gzip\""),
        }
    }

    /// The answer to a request with `headers`: the gzipped form when accepted, 304
    /// when `If-None-Match` names the form's ETag (or is `*`).
    pub(crate) fn answer(&self, headers: &HeaderMap) -> Response {
        let gzipped = self.gzipped.as_ref().filter(|_| accepts_gzip(headers));
        let etag = if gzipped.is_some() {
            &self.etag_gzip
        } else {
            &self.etag
        };
        let mut response = if none_match(headers, etag) {
            StatusCode::NOT_MODIFIED.into_response()
        } else {
            let mut response = match gzipped {
                Some(bytes) => {
                    let mut response = Body::from(Bytes::clone(bytes)).into_response();
                    response
                        .headers_mut()
                        .insert(header::CONTENT_ENCODING, HeaderValue::from_static("gzip"));
                    response
                }
                None => Body::from(self.identity).into_response(),
            };
            response.headers_mut().insert(
                header::CONTENT_TYPE,
                HeaderValue::from_static(self.content_type),
            );
            response
        };
        let headers = response.headers_mut();
        if let Ok(etag) = HeaderValue::from_str(etag) {
            headers.insert(header::ETAG, etag);
        }
        headers.insert(
            header::CACHE_CONTROL,
            HeaderValue::from_static(self.cache_control),
        );
        if self.gzipped.is_some() {
            headers.insert(
                header::VARY,
                HeaderValue::from_static(header::ACCEPT_ENCODING.as_str()),
            );
        }
        response
    }
}

/// Whether `If-None-Match` in `headers` names `etag` or is `*` (weak comparison, RFC
/// 9110 §13.1.2).
fn none_match(headers: &HeaderMap, etag: &str) -> bool {
    headers
        .get_all(header::IF_NONE_MATCH)
        .iter()
        .filter_map(|value| value.to_str().ok())
        .flat_map(|value| value.split(','))
        .map(str::trim)
        .any(|tag| tag == "*" || tag.strip_prefix("W/").unwrap_or(tag) == etag)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn with(name: header::HeaderName, value: &'static str) -> HeaderMap {
        let mut headers = HeaderMap::new();
        headers.insert(name, HeaderValue::from_static(value));
        headers
    }

    #[test]
    fn gzip_is_accepted_as_rfc_9110_says() {
        for accepted in [
            "gzip",
            "deflate, gzip;q=0.5",
            "br;q=1.0, GZIP",
            "x-gzip",
            "*",
            "identity;q=0.5, *;q=0.1",
        ] {
            assert!(
                accepts_gzip(&with(header::ACCEPT_ENCODING, accepted)),
                "{accepted}"
            );
        }
        for refused in [
            "",
            "identity",
            "br, deflate",
            "gzip;q=0",
            "*, gzip;q=0",
            "*;q=0",
        ] {
            assert!(
                !accepts_gzip(&with(header::ACCEPT_ENCODING, refused)),
                "{refused}"
            );
        }
        assert!(!accepts_gzip(&HeaderMap::new()));
    }

    #[test]
    fn if_none_match_compares_weakly_and_takes_lists_and_star() {
        let etag = "\"0123456789abcdef\"";
        for matching in [
            "\"0123456789abcdef\"",
            "W/\"0123456789abcdef\"",
            "\"other\", \"0123456789abcdef\"",
            "*",
        ] {
            assert!(
                none_match(&with(header::IF_NONE_MATCH, matching), etag),
                "{matching}"
            );
        }
        for other in [
            "\"0123456789abcdee\"",
            "\"0123456789abcdef-gzip\"",
            "0123456789abcdef",
        ] {
            assert!(
                !none_match(&with(header::IF_NONE_MATCH, other), etag),
                "{other}"
            );
        }
    }
}
