//! Just enough HTTP/1.1 for the viewer: GET requests with a bounded head and no body, one response per
//! connection (`Connection: close`), every error a status with one line of text. The sockets themselves are
//! `conn.rs`'s.

/// The longest request head (request line and headers) read; a longer one is answered 431.
pub const MAX_HEAD_BYTES: usize = 8 * 1024;
/// The longest request target (path and query); a longer one is answered 414.
pub const MAX_TARGET_BYTES: usize = 2 * 1024;
/// The most headers a request may have.
const MAX_HEADERS: usize = 64;

/// A request the viewer serves: its path and its query parameters, percent-decoded.
#[derive(Debug, PartialEq)]
pub struct Request {
    pub path: String,
    pub query: Vec<(String, String)>,
}

/// An error answered to the client: a status and one line saying what was wrong.
#[derive(Debug, Clone, PartialEq)]
pub struct HttpError {
    pub status: u16,
    pub message: String,
}

impl HttpError {
    pub fn new(status: u16, message: impl Into<String>) -> HttpError {
        HttpError { status, message: message.into() }
    }

    /// 400: a parameter that is not what was expected.
    pub fn bad(message: impl Into<String>) -> HttpError {
        HttpError::new(400, message)
    }

    /// An error of the API, answered with the status of its kind ([`status_of`]).
    pub fn of(e: &raypatch::Error) -> HttpError {
        HttpError::new(status_of(e.kind()), e.to_string())
    }

    /// The same error, its message said to be about `what` (a parameter, or the render).
    pub fn about(self, what: &str) -> HttpError {
        HttpError { message: format!("{what}: {}", self.message), ..self }
    }

    pub fn response(&self) -> Response {
        // One line, whatever the message holds.
        let line = self.message.replace(['\r', '\n'], " ");
        Response::new(self.status, "text/plain; charset=utf-8", format!("{line}\n").into_bytes())
    }
}

/// The viewer's one table from whose fault an API error is to the HTTP status answered: the request's (400);
/// a file's (422: the request was understood but the model or scene data it names cannot be processed; 404
/// would say the client named something missing, and clients name nothing but indices); the device's (503:
/// the server cannot render now); the viewer's own bug (500).
pub fn status_of(kind: raypatch::ErrorKind) -> u16 {
    match kind {
        raypatch::ErrorKind::Input => 400,
        raypatch::ErrorKind::File => 422,
        raypatch::ErrorKind::Device => 503,
        raypatch::ErrorKind::Internal => 500,
    }
}

/// A response: status, content type, body and extra headers.
pub struct Response {
    pub status: u16,
    pub content_type: &'static str,
    pub body: Vec<u8>,
    pub headers: Vec<(&'static str, String)>,
}

impl Response {
    pub fn new(status: u16, content_type: &'static str, body: Vec<u8>) -> Response {
        Response { status, content_type, body, headers: Vec::new() }
    }

    pub fn ok(content_type: &'static str, body: impl Into<Vec<u8>>) -> Response {
        Response::new(200, content_type, body.into())
    }

    /// The response as sent: head and body.
    pub fn into_bytes(self) -> Vec<u8> {
        let mut head = format!(
            "HTTP/1.1 {} {}\r\nContent-Type: {}\r\nContent-Length: {}\r\nConnection: close\r\n\
             Cache-Control: no-store\r\nX-Content-Type-Options: nosniff\r\n",
            self.status,
            reason(self.status),
            self.content_type,
            self.body.len()
        );
        for (name, value) in &self.headers {
            head.push_str(&format!("{name}: {value}\r\n"));
        }
        head.push_str("\r\n");
        let mut bytes = head.into_bytes();
        bytes.extend_from_slice(&self.body);
        bytes
    }
}

fn reason(status: u16) -> &'static str {
    match status {
        200 => "OK",
        400 => "Bad Request",
        404 => "Not Found",
        405 => "Method Not Allowed",
        409 => "Conflict",
        413 => "Payload Too Large",
        414 => "URI Too Long",
        422 => "Unprocessable Content",
        429 => "Too Many Requests",
        431 => "Request Header Fields Too Large",
        500 => "Internal Server Error",
        503 => "Service Unavailable",
        _ => "Error",
    }
}

/// Where the head in `bytes` ends (the index of its final blank line), looking only at what follows `from`
/// and the three bytes before it (the bytes before were searched already).
pub fn head_end(bytes: &[u8], from: usize) -> Option<usize> {
    let start = from.saturating_sub(3);
    bytes[start..].windows(4).position(|w| w == b"\r\n\r\n").map(|i| start + i)
}

/// Parses a request head (without its final blank line): a GET with no body.
pub fn parse_head(head: &[u8]) -> Result<Request, HttpError> {
    if head.len() > MAX_HEAD_BYTES {
        return Err(HttpError::new(431, format!("request: the head is over {MAX_HEAD_BYTES} bytes")));
    }
    let text = std::str::from_utf8(head).map_err(|_| HttpError::bad("request: the head is not UTF-8"))?;
    let mut lines = text.split("\r\n");
    let request_line = lines.next().unwrap_or_default();
    let mut parts = request_line.split(' ');
    let (method, target, version) = match (parts.next(), parts.next(), parts.next(), parts.next()) {
        (Some(m), Some(t), Some(v), None) => (m, t, v),
        _ => return Err(HttpError::bad("request line: expected `METHOD TARGET HTTP/1.1`")),
    };
    if !matches!(version, "HTTP/1.0" | "HTTP/1.1") {
        return Err(HttpError::bad(format!("request line: version {version:?}, expected HTTP/1.0 or HTTP/1.1")));
    }
    if method != "GET" {
        return Err(HttpError::new(405, format!("method {method:?}: only GET is served")));
    }
    if target.len() > MAX_TARGET_BYTES {
        return Err(HttpError::new(414, format!("request target: over {MAX_TARGET_BYTES} bytes")));
    }
    let mut headers = 0;
    for line in lines {
        headers += 1;
        if headers > MAX_HEADERS {
            return Err(HttpError::new(431, format!("request: more than {MAX_HEADERS} headers")));
        }
        let (name, value) =
            line.split_once(':').ok_or_else(|| HttpError::bad(format!("header {line:?}: expected `Name: value`")))?;
        let value = value.trim();
        if name.eq_ignore_ascii_case("transfer-encoding")
            || (name.eq_ignore_ascii_case("content-length") && value != "0")
        {
            return Err(HttpError::new(413, "request body: not accepted (the viewer serves GET requests only)"));
        }
    }
    let (path, query) = target.split_once('?').unwrap_or((target, ""));
    if !path.starts_with('/') {
        return Err(HttpError::bad(format!("request target {target:?}: expected a path starting with /")));
    }
    Ok(Request { path: decode(path, "path")?, query: parse_query(query)? })
}

/// `a=1&b=2` as decoded pairs; a parameter given twice is an error.
fn parse_query(query: &str) -> Result<Vec<(String, String)>, HttpError> {
    let mut pairs: Vec<(String, String)> = Vec::new();
    for part in query.split('&').filter(|p| !p.is_empty()) {
        let (key, value) = part.split_once('=').unwrap_or((part, ""));
        let key = decode(key, "parameter name")?;
        if pairs.iter().any(|(k, _)| *k == key) {
            return Err(HttpError::bad(format!("parameter `{key}`: given twice")));
        }
        let value = decode(value, &key)?;
        pairs.push((key, value));
    }
    Ok(pairs)
}

/// Percent-decoding (and `+` as a space), as browsers encode query strings.
fn decode(text: &str, what: &str) -> Result<String, HttpError> {
    let bad = || HttpError::bad(format!("{what}: invalid percent-encoding or not UTF-8"));
    let bytes = text.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        match bytes[i] {
            b'%' => {
                let hex = bytes.get(i + 1..i + 3).and_then(|h| std::str::from_utf8(h).ok()).ok_or_else(bad)?;
                out.push(u8::from_str_radix(hex, 16).map_err(|_| bad())?);
                i += 3;
            }
            b'+' => {
                out.push(b' ');
                i += 1;
            }
            b => {
                out.push(b);
                i += 1;
            }
        }
    }
    String::from_utf8(out).map_err(|_| bad())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_get_is_parsed_and_its_query_decoded() {
        let request = parse_head(b"GET /render.png?pose=1%2C2+3&size=8x4 HTTP/1.1\r\nHost: x").unwrap();
        assert_eq!(request.path, "/render.png");
        assert_eq!(request.query, vec![("pose".into(), "1,2 3".into()), ("size".into(), "8x4".into())]);
    }

    #[test]
    fn a_heads_end_is_found_across_reads() {
        let bytes = b"GET / HTTP/1.1\r\nHost: x\r\n\r\n";
        let end = bytes.len() - 4;
        assert_eq!(head_end(bytes, 0), Some(end));
        // The blank line split between two reads is still found from where the second read began.
        assert_eq!(head_end(bytes, end + 2), Some(end));
        assert_eq!(head_end(&bytes[..end + 3], 0), None);
    }

    #[test]
    fn malformed_heads_are_client_errors() {
        let status = |head: &[u8]| parse_head(head).unwrap_err().status;
        assert_eq!(status(b"POST / HTTP/1.1"), 405);
        assert_eq!(status(b"GET / HTTP/1.1\r\nContent-Length: 5"), 413);
        assert_eq!(status(b"GET / HTTP/1.1\r\nTransfer-Encoding: chunked"), 413);
        assert_eq!(status(b"GET /?a=1&a=2 HTTP/1.1"), 400);
        assert_eq!(status(b"GET /?a=%zz HTTP/1.1"), 400);
        assert_eq!(status(b"GET /?a=%ff HTTP/1.1"), 400);
        assert_eq!(status(b"GET / HTTP/2"), 400);
        assert_eq!(status(b"GET  HTTP/1.1"), 400);
        assert_eq!(status(b"garbage"), 400);
        assert_eq!(status(b"GET http://x/ HTTP/1.1"), 400);
        assert_eq!(status(b"GET / HTTP/1.1\r\nno colon"), 400);
        let long = format!("GET /?{} HTTP/1.1", "a".repeat(MAX_TARGET_BYTES));
        assert_eq!(status(long.as_bytes()), 414);
        let many = format!("GET / HTTP/1.1{}", "\r\nX: 1".repeat(MAX_HEADERS + 1));
        assert_eq!(status(many.as_bytes()), 431);
    }
}
