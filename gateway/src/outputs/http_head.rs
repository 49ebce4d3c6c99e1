//! The request head of the `/metrics` endpoint's minimal HTTP/1.1: read whole (a
//! request may arrive in several segments), bounded in size, checked before use.

/// Longest request head accepted, bytes (request line and headers).
pub const MAX_HEAD_LEN: usize = 8192;

/// A request line that was understood.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RequestLine<'a> {
    /// `GET`, `HEAD`, ...
    pub method: &'a str,
    /// The path without the query.
    pub path: &'a str,
}

/// Why a head cannot be answered with a page.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum HeadError {
    /// Longer than [`MAX_HEAD_LEN`] without its end.
    #[error("request head longer than {MAX_HEAD_LEN} bytes")]
    TooLong,
    /// Not `METHOD SP TARGET SP HTTP/1.x`, or a header line without a colon, or not
    /// text.
    #[error("malformed request head")]
    Malformed,
}

impl HeadError {
    /// The response status line's code and reason.
    pub fn status(self) -> &'static str {
        match self {
            HeadError::TooLong => "431 Request Header Fields Too Large",
            HeadError::Malformed => "400 Bad Request",
        }
    }
}

/// Where the head received so far ends: the index after its blank line, `Ok(None)`
/// while it is incomplete, an error once it is longer than [`MAX_HEAD_LEN`].
pub fn head_end(received: &[u8]) -> Result<Option<usize>, HeadError> {
    let searched = &received[..received.len().min(MAX_HEAD_LEN)];
    let end = searched
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .map(|at| at + 4)
        .or_else(|| {
            searched
                .windows(2)
                .position(|w| w == b"\n\n")
                .map(|at| at + 2)
        });
    match end {
        Some(end) => Ok(Some(end)),
        None if received.len() >= MAX_HEAD_LEN => Err(HeadError::TooLong),
        None => Ok(None),
    }
}

/// Parse a whole head (as delimited by [`head_end`]).
pub fn parse(head: &[u8]) -> Result<RequestLine<'_>, HeadError> {
    let text = std::str::from_utf8(head).map_err(|_| HeadError::Malformed)?;
    let mut lines = text.lines();
    let request = lines.next().ok_or(HeadError::Malformed)?;
    let mut parts = request.split(' ');
    let (Some(method), Some(target), Some(version), None) =
        (parts.next(), parts.next(), parts.next(), parts.next())
    else {
        return Err(HeadError::Malformed);
    };
    let token = |s: &str| !s.is_empty() && s.bytes().all(|b| b.is_ascii_alphabetic());
    if !token(method) || !target.starts_with('/') || !version.starts_with("HTTP/1.") {
        return Err(HeadError::Malformed);
    }
    if target.bytes().any(|b| b.is_ascii_control()) {
        return Err(HeadError::Malformed);
    }
    if lines
        .take_while(|line| !line.is_empty())
        .any(|line| !line.contains(':'))
    {
        return Err(HeadError::Malformed);
    }
    let path = target.split('?').next().unwrap_or(target);
    Ok(RequestLine { method, path })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_head_is_whole_only_after_its_blank_line() {
        let request = b"GET /metrics HTTP/1.1\r\nHost: x\r\n\r\n";
        for cut in 0..request.len() {
            assert_eq!(head_end(&request[..cut]), Ok(None), "{cut}");
        }
        assert_eq!(head_end(request), Ok(Some(request.len())));
        assert_eq!(head_end(b"GET / HTTP/1.0\n\n"), Ok(Some(16)));
        assert_eq!(head_end(&[b'a'; MAX_HEAD_LEN]), Err(HeadError::TooLong));
    }

    #[test]
    fn request_lines_are_checked() {
        assert_eq!(
            parse(b"GET /metrics?x=1 HTTP/1.1\r\nHost: a\r\n\r\n"),
            Ok(RequestLine {
                method: "GET",
                path: "/metrics"
            })
        );
        for bad in [
            &b"GET /metrics\r\n\r\n"[..],
            b"GET  /metrics HTTP/1.1\r\n\r\n",
            b"GET metrics HTTP/1.1\r\n\r\n",
            b"GET /metrics HTTP/2\r\n\r\n",
            b"G3T /metrics HTTP/1.1\r\n\r\n",
            b"GET /metrics HTTP/1.1\r\nno colon here\r\n\r\n",
            b"GET /\xff HTTP/1.1\r\n\r\n",
            b"\r\n\r\n",
        ] {
            assert_eq!(parse(bad), Err(HeadError::Malformed), "{bad:?}");
        }
    }
}
