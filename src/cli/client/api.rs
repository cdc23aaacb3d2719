//! The HTTP side of the client: one `reqwest::Client`, the API key, and
//! the translation of every way a request can go wrong into a [`Failure`]
//! with the exit code the module docs promise.

use std::time::Duration;

use anyhow::anyhow;
use reqwest::header::{HeaderValue, RETRY_AFTER};
use reqwest::{Method, RequestBuilder, Response, StatusCode};
use serde::de::DeserializeOwned;
use treemorph_api::{ErrorBody, ErrorCode};
use url::Url;

use super::{EXIT_BUSY, EXIT_NOT_FOUND, EXIT_UNAUTHORIZED, EXIT_UNREACHABLE};
use crate::cli::{EXIT_FAILURE, EXIT_INVALID_INPUT, EXIT_USAGE, Failure};

/// How long connecting may take before the server counts as unreachable.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(10);
/// Longest silence on an open connection. The server answers within its
/// request timeout (60 s by default) and sends an SSE keep-alive every
/// 15 s, so a longer silence means the connection is dead (the watcher
/// then reconnects).
const READ_TIMEOUT: Duration = Duration::from_secs(120);

/// An error response of the server, as the user needs it: the stable code
/// and the message (`code: message`).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{code}: {message}{}", retry_hint(*.retry_after))]
pub struct ServerError {
    /// The HTTP status.
    pub status: u16,
    /// The error code as sent (a newer server may send codes this client
    /// does not know; they are shown as they are).
    pub code: String,
    /// The code, when it is one of ours.
    pub known: Option<ErrorCode>,
    /// The server's message.
    pub message: String,
    /// Seconds to wait before retrying (`Retry-After` of a 429 or 503).
    pub retry_after: Option<u64>,
}

fn retry_hint(after: Option<u64>) -> String {
    after.map_or_else(String::new, |s| format!(" (retry after {s} s)"))
}

impl ServerError {
    /// Builds the error from a response's status, headers and body; bodies
    /// that are not our error document (a proxy's HTML page) still give a
    /// readable code from the HTTP status.
    pub fn from_parts(status: StatusCode, retry_after: Option<&HeaderValue>, body: &[u8]) -> Self {
        let retry_after = retry_after
            .and_then(|v| v.to_str().ok())
            .and_then(|v| v.trim().parse().ok());
        if let Ok(body) = serde_json::from_slice::<ErrorBody>(body) {
            return ServerError {
                status: status.as_u16(),
                code: body.error.code.as_str().to_owned(),
                known: Some(body.error.code),
                message: body.error.message,
                retry_after,
            };
        }
        let value: serde_json::Value = serde_json::from_slice(body).unwrap_or_default();
        let error = &value["error"];
        if let (Some(code), Some(message)) = (error["code"].as_str(), error["message"].as_str()) {
            return ServerError {
                status: status.as_u16(),
                code: code.to_owned(),
                known: None,
                message: message.to_owned(),
                retry_after,
            };
        }
        let text = String::from_utf8_lossy(body);
        let text = text.trim();
        let mut message = status.canonical_reason().unwrap_or("error").to_owned();
        if !text.is_empty() {
            let snippet: String = text.chars().take(200).collect();
            message = format!("{message}: {snippet}");
        }
        ServerError {
            status: status.as_u16(),
            code: format!("http_{}", status.as_u16()),
            known: None,
            message,
            retry_after,
        }
    }

    /// The exit code of this error (see the module docs of `client`).
    pub fn exit_code(&self) -> u8 {
        match self.known {
            Some(ErrorCode::Unauthorized) => EXIT_UNAUTHORIZED,
            Some(ErrorCode::NotFound | ErrorCode::TreeNotFound) => EXIT_NOT_FOUND,
            Some(ErrorCode::RateLimited | ErrorCode::QueueFull) => EXIT_BUSY,
            Some(code) if code.is_client_error() => EXIT_INVALID_INPUT,
            Some(_) => EXIT_FAILURE,
            None => match self.status {
                401 => EXIT_UNAUTHORIZED,
                404 => EXIT_NOT_FOUND,
                429 => EXIT_BUSY,
                400..=499 => EXIT_INVALID_INPUT,
                _ => EXIT_FAILURE,
            },
        }
    }

    /// Whether retrying later may succeed (the server or a proxy in front
    /// of it is failing or restarting).
    pub fn is_transient(&self) -> bool {
        self.status >= 500
    }
}

/// A failure carrying a [`ServerError`].
pub fn server_failure(error: ServerError) -> Failure {
    Failure {
        code: error.exit_code(),
        error: error.into(),
    }
}

/// A failure with an explicit exit code.
pub fn failure(code: u8, error: impl Into<anyhow::Error>) -> Failure {
    Failure {
        code,
        error: error.into(),
    }
}

/// Whether retrying may help: the server was unreachable or answered 5xx.
pub fn is_transient(f: &Failure) -> bool {
    f.code == EXIT_UNREACHABLE
        || f.error
            .downcast_ref::<ServerError>()
            .is_some_and(ServerError::is_transient)
}

/// The service: base URL, API key and connection pool.
#[derive(Debug)]
pub struct Api {
    http: reqwest::Client,
    base: Url,
    key: Option<String>,
}

impl Api {
    /// A client of the server at `server` (an `http` or `https` URL).
    pub fn new(server: &str, key: Option<String>) -> Result<Api, Failure> {
        let mut base = Url::parse(server)
            .map_err(|e| failure(EXIT_USAGE, anyhow!("--server {server:?} is not a URL: {e}")))?;
        if !matches!(base.scheme(), "http" | "https") || base.cannot_be_a_base() {
            return Err(failure(
                EXIT_USAGE,
                anyhow!("--server {server:?} must be an http:// or https:// URL"),
            ));
        }
        // Routes are joined below the base path, so a server mounted under
        // a prefix (`https://host/treemorph`) works too.
        if !base.path().ends_with('/') {
            let path = format!("{}/", base.path());
            base.set_path(&path);
        }
        let http = crate::tls::client_builder()
            .connect_timeout(CONNECT_TIMEOUT)
            .read_timeout(READ_TIMEOUT)
            .user_agent(concat!("treemorph-client/", env!("CARGO_PKG_VERSION")))
            .build()
            .map_err(|e| failure(EXIT_FAILURE, anyhow!(e).context("building the HTTP client")))?;
        Ok(Api {
            http,
            base,
            key: key.filter(|k| !k.is_empty()),
        })
    }

    /// The absolute URL of a server path (`/v1/...`, as in the job
    /// document's links).
    pub fn url(&self, path: &str) -> Result<Url, Failure> {
        self.base
            .join(path.trim_start_matches('/'))
            .map_err(|e| failure(EXIT_FAILURE, anyhow!("bad path {path:?}: {e}")))
    }

    /// The URL of `/v1/{segments...}`, each segment percent-encoded (ids
    /// come from the command line and must not escape their route).
    pub fn v1(&self, segments: &[&str]) -> Result<Url, Failure> {
        let mut url = self.base.clone();
        url.path_segments_mut()
            .map_err(|()| failure(EXIT_USAGE, anyhow!("--server cannot be a base URL")))?
            .pop_if_empty()
            .push("v1")
            .extend(segments);
        Ok(url)
    }

    /// A request with the API key.
    pub fn request(&self, method: Method, url: Url) -> RequestBuilder {
        let request = self.http.request(method, url);
        match &self.key {
            Some(key) => request.bearer_auth(key),
            None => request,
        }
    }

    /// Sends a request; a non-2xx answer becomes a [`ServerError`] failure.
    pub async fn send(&self, request: RequestBuilder) -> Result<Response, Failure> {
        let response = request.send().await.map_err(|e| self.transport(e))?;
        if response.status().is_success() {
            return Ok(response);
        }
        let status = response.status();
        let retry_after = response.headers().get(RETRY_AFTER).cloned();
        // An error body that cannot be read is still an error of `status`.
        let body = response.bytes().await.unwrap_or_default();
        Err(server_failure(ServerError::from_parts(
            status,
            retry_after.as_ref(),
            &body,
        )))
    }

    /// Sends a request and decodes its JSON answer, returning the typed
    /// document and the raw one (for `--json`).
    pub async fn json<T: DeserializeOwned>(
        &self,
        request: RequestBuilder,
    ) -> Result<(T, serde_json::Value), Failure> {
        let response = self.send(request).await?;
        let bytes = response.bytes().await.map_err(|e| self.transport(e))?;
        let raw: serde_json::Value = serde_json::from_slice(&bytes).map_err(|e| {
            failure(
                EXIT_FAILURE,
                anyhow!("the server's answer is not JSON ({e}); is --server a treemorph service?"),
            )
        })?;
        let typed = T::deserialize(&raw).map_err(|e| {
            failure(
                EXIT_FAILURE,
                anyhow!("unexpected answer from the server ({e}): {raw}"),
            )
        })?;
        Ok((typed, raw))
    }

    /// Maps a transport error: cannot connect or no answer in time is
    /// "unreachable", anything else a plain failure.
    pub fn transport(&self, e: reqwest::Error) -> Failure {
        let code = if e.is_connect() || e.is_timeout() {
            EXIT_UNREACHABLE
        } else {
            EXIT_FAILURE
        };
        let what = if code == EXIT_UNREACHABLE {
            format!("unreachable: cannot reach the server at {}", self.base)
        } else {
            format!("talking to the server at {}", self.base)
        };
        failure(code, anyhow::Error::new(e).context(what))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn error_bodies_give_code_message_and_exit_code() {
        let body = br#"{"error": {"code": "tree_not_found", "message": "no tree abc"}}"#;
        let e = ServerError::from_parts(StatusCode::NOT_FOUND, None, body);
        assert_eq!(e.to_string(), "tree_not_found: no tree abc");
        assert_eq!(e.exit_code(), EXIT_NOT_FOUND);

        let retry = HeaderValue::from_static("3");
        let body = br#"{"error": {"code": "queue_full", "message": "busy"}}"#;
        let e = ServerError::from_parts(StatusCode::TOO_MANY_REQUESTS, Some(&retry), body);
        assert_eq!(e.to_string(), "queue_full: busy (retry after 3 s)");
        assert_eq!(e.exit_code(), EXIT_BUSY);

        let body = br#"{"error": {"code": "invalid_sketch", "message": "too few points"}}"#;
        let e = ServerError::from_parts(StatusCode::UNPROCESSABLE_ENTITY, None, body);
        assert_eq!(e.exit_code(), EXIT_INVALID_INPUT);

        let body = br#"{"error": {"code": "unauthorized", "message": "key"}}"#;
        let e = ServerError::from_parts(StatusCode::UNAUTHORIZED, None, body);
        assert_eq!(e.exit_code(), EXIT_UNAUTHORIZED);

        let body = br#"{"error": {"code": "unavailable", "message": "db"}}"#;
        let e = ServerError::from_parts(StatusCode::SERVICE_UNAVAILABLE, None, body);
        assert_eq!(e.exit_code(), EXIT_FAILURE);
        assert!(e.is_transient());
    }

    #[test]
    fn foreign_bodies_still_give_a_readable_error() {
        let body = br#"{"error": {"code": "brand_new_code", "message": "m"}}"#;
        let e = ServerError::from_parts(StatusCode::CONFLICT, None, body);
        assert_eq!(e.to_string(), "brand_new_code: m");
        assert_eq!(e.exit_code(), EXIT_INVALID_INPUT);

        let e = ServerError::from_parts(StatusCode::BAD_GATEWAY, None, b"<html>bad gateway</html>");
        assert_eq!(
            e.to_string(),
            "http_502: Bad Gateway: <html>bad gateway</html>"
        );
        assert_eq!(e.exit_code(), EXIT_FAILURE);
        let e = ServerError::from_parts(StatusCode::NOT_FOUND, None, b"");
        assert_eq!(e.exit_code(), EXIT_NOT_FOUND);
    }

    #[test]
    fn server_urls_are_validated_and_joined_below_their_path() {
        assert_eq!(Api::new("ftp://x", None).unwrap_err().code, EXIT_USAGE);
        assert_eq!(Api::new("not a url", None).unwrap_err().code, EXIT_USAGE);
        let api = Api::new("https://example.com/tm", None).unwrap();
        assert_eq!(
            api.url("/v1/jobs/a").unwrap().as_str(),
            "https://example.com/tm/v1/jobs/a"
        );
        let api = Api::new("http://127.0.0.1:8080", None).unwrap();
        assert_eq!(
            api.url("/v1/jobs/a/frames/3.glb").unwrap().as_str(),
            "http://127.0.0.1:8080/v1/jobs/a/frames/3.glb"
        );
        assert_eq!(
            api.v1(&["jobs", "../trees", "events"]).unwrap().as_str(),
            "http://127.0.0.1:8080/v1/jobs/..%2Ftrees/events"
        );
    }
}
