//! The HTTP service (`treemorph serve`): one module per resource, the
//! shared [`AppState`], the middleware and the server loop.
//!
//! - [`router`] builds the axum [`Router`] (for in-process tests with
//!   `oneshot`), [`serve`] runs it on a listener with workers (for real
//!   socket tests and the binary).
//! - **Uniform errors.** Handlers return [`ApiError`]; our own extractors
//!   turn JSON, query and content-type problems into the same body, and a
//!   last middleware gives any remaining non-JSON error response (axum's
//!   405, the fallback 404, the request timeout, body-limit rejections) the
//!   uniform body with a code from its status.
//! - **Tenancy.** With API keys configured, every `/v1` request needs
//!   `Authorization: Bearer KEY`; the key's fingerprint is the *owner* of
//!   everything it creates, and every query is scoped by owner, so another
//!   key's ids answer 404 exactly like ids that never existed.
//! - **Rate limit.** A token bucket per owner (`--rate-limit`,
//!   `--rate-burst`); 429 `rate_limited` with `Retry-After`.
//! - **Timeouts.** Request handling is bounded by `--request-timeout`
//!   except on the SSE and stream routes, which last as long as their job,
//!   and a tree upload's body, which may take as long as it keeps flowing.
//!   Slow clients are bounded by hyper's `header_read_timeout`
//!   (`--header-read-timeout`; plain `axum::serve` has none), slow bodies
//!   by a minimum average rate ([`slow_body`], `--min-body-rate`), and
//!   uploads by their size limit.
//! - **Shutdown.** On the shutdown signal the listener closes, workers
//!   drain (see [`crate::jobs::worker::Pool::shutdown`]), live SSE and
//!   stream responses end (clients reconnect elsewhere), and open
//!   connections get the grace period to finish.

pub mod blob;
pub mod events;
pub mod extract;
pub mod health;
pub mod jobs;
pub mod linger;
pub mod openapi;
pub mod quota;
pub mod renders;
pub mod resample;
pub mod slow_body;
pub mod stream;
pub mod streamed;
pub mod trees;
pub mod web;

use std::collections::HashMap;
use std::future::Future;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use axum::Router;
use axum::body::Body;
use axum::extract::{MatchedPath, Request, State};
use axum::http::{HeaderValue, Method, StatusCode, header};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use sha2::Digest;
use tokio::sync::watch;
use treemorph_api::{ErrorBody, ErrorCode};
use utoipa_axum::router::OpenApiRouter;

use crate::config::Settings;
use crate::error::{ApiError, code_for_status};
use crate::jobs::tree_cache::TreeCache;
use crate::jobs::{Hub, Services};
use crate::pipeline::Runner;
use crate::store::{Blobs, Db};
use crate::telemetry::Metrics;

/// The owner of the current request's resources.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Owner(pub String);

/// Shared state of the HTTP handlers.
#[derive(Clone, Debug)]
pub struct AppState {
    /// Database, blobs, hub, runner, metrics, settings.
    pub services: Services,
    /// API key fingerprints → owner ids (empty: open API).
    pub keys: Arc<HashMap<String, String>>,
    /// Per-owner token buckets.
    pub limiter: Arc<RateLimiter>,
    /// Frames rendered on request.
    pub renders: Arc<renders::RenderCache>,
    /// Turns true when the server shuts down (live streams end).
    pub shutdown: watch::Receiver<bool>,
    shutdown_tx: Arc<watch::Sender<bool>>,
}

/// Largest request head (request line and headers) the server reads.
const MAX_HEAD_BYTES: usize = 64 * 1024;

impl AppState {
    /// Connects to the database (migrating it) and the blob store.
    pub async fn new(settings: Settings, runner: Arc<dyn Runner>) -> anyhow::Result<AppState> {
        std::fs::create_dir_all(&settings.data_dir)?;
        std::fs::create_dir_all(settings.data_dir.join("tmp"))?;
        let db = Db::connect(&settings.database_url()).await?;
        db.migrate().await?;
        let blobs = Blobs::open(&settings.blob_url()?)?;
        let webhook_key = crate::jobs::webhooks::load_or_create_key(&settings)?;
        let keys = settings
            .all_api_keys()?
            .into_iter()
            .map(|k| {
                let digest = hex(&sha2::Sha256::digest(k.as_bytes()));
                let owner = format!("key_{}", &digest[..16]);
                (digest, owner)
            })
            .collect();
        let limiter = RateLimiter::new(settings.rate_limit, settings.rate_burst);
        let (tx, rx) = watch::channel(false);
        // Workers read the cache for jobs, API processes for renders on
        // request (`frame.glb?t=`).
        let trees = TreeCache::new(settings.tree_cache_mb.saturating_mul(1 << 20));
        let store = crate::store::renders::RenderStore::new(
            blobs.clone(),
            db.clone(),
            settings.render_store_mb.saturating_mul(1 << 20),
        );
        let renders = renders::RenderCache::new(settings.render_cache_mb.saturating_mul(1 << 20))
            .with_store(store);
        Ok(AppState {
            services: Services {
                trees: Arc::new(trees),
                settings: Arc::new(settings),
                db,
                blobs,
                hub: Arc::new(Hub::default()),
                runner,
                metrics: Arc::new(Metrics::default()),
                webhook_key: Arc::new(webhook_key),
            },
            keys: Arc::new(keys),
            limiter: Arc::new(limiter),
            renders: Arc::new(renders),
            shutdown: rx,
            shutdown_tx: Arc::new(tx),
        })
    }

    /// The settings.
    pub fn settings(&self) -> &Settings {
        &self.services.settings
    }

    /// How long a request may take (`--request-timeout`).
    pub fn request_timeout(&self) -> Duration {
        Duration::from_secs(self.settings().request_timeout.max(1))
    }

    /// Signals live streams to end.
    pub fn begin_shutdown(&self) {
        let _ = self.shutdown_tx.send(true);
    }
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// A token bucket per owner.
#[derive(Debug)]
pub struct RateLimiter {
    rate: f64,
    burst: f64,
    buckets: Mutex<HashMap<String, (f64, Instant)>>,
}

impl RateLimiter {
    /// `rate` tokens per second (0 disables), at most `burst` stored.
    pub fn new(rate: f64, burst: u32) -> RateLimiter {
        RateLimiter {
            rate,
            burst: f64::from(burst.max(1)),
            buckets: Mutex::new(HashMap::new()),
        }
    }

    /// Takes a token for `owner`, or says how many seconds until one is
    /// available.
    pub fn check(&self, owner: &str) -> Result<(), u64> {
        if self.rate <= 0.0 {
            return Ok(());
        }
        let now = Instant::now();
        let mut buckets = self.buckets.lock().expect("rate limiter lock");
        let (tokens, last) = buckets.entry(owner.to_owned()).or_insert((self.burst, now));
        *tokens = (*tokens + now.duration_since(*last).as_secs_f64() * self.rate).min(self.burst);
        *last = now;
        if *tokens >= 1.0 {
            *tokens -= 1.0;
            Ok(())
        } else {
            Err(((1.0 - *tokens) / self.rate).ceil().max(1.0) as u64)
        }
    }
}

async fn authenticate(State(state): State<AppState>, mut request: Request, next: Next) -> Response {
    let owner = if state.keys.is_empty() {
        "anonymous".to_owned()
    } else {
        let presented = request
            .headers()
            .get(header::AUTHORIZATION)
            .and_then(|v| v.to_str().ok())
            .and_then(|v| {
                v.strip_prefix("Bearer ")
                    .or_else(|| v.strip_prefix("bearer "))
            })
            .map(str::trim);
        let owner = presented
            .map(|k| hex(&sha2::Sha256::digest(k.as_bytes())))
            .and_then(|digest| state.keys.get(&digest).cloned());
        match owner {
            Some(owner) => owner,
            None => {
                let mut r = ApiError::new(
                    ErrorCode::Unauthorized,
                    "a valid API key is required: Authorization: Bearer KEY",
                )
                .into_response();
                r.headers_mut()
                    .insert(header::WWW_AUTHENTICATE, HeaderValue::from_static("Bearer"));
                return r;
            }
        }
    };
    if let Err(wait) = state.limiter.check(&owner) {
        return ApiError::new(ErrorCode::RateLimited, "too many requests for this API key")
            .retry_after(wait)
            .into_response();
    }
    request.extensions_mut().insert(Owner(owner));
    next.run(request).await
}

async fn track(State(state): State<AppState>, request: Request, next: Next) -> Response {
    let route = request
        .extensions()
        .get::<MatchedPath>()
        .map_or_else(|| "unmatched".to_owned(), |p| p.as_str().to_owned());
    let method = request.method().clone();
    let started = Instant::now();
    let response = next.run(request).await;
    state.services.metrics.observe_http(
        method.as_str(),
        &route,
        response.status().as_u16(),
        started.elapsed(),
    );
    response
}

/// Gives every error response without a JSON body the uniform error body.
async fn uniform_errors(request: Request, next: Next) -> Response {
    let response = next.run(request).await;
    let status = response.status();
    if !(status.is_client_error() || status.is_server_error()) {
        return response;
    }
    let is_json = response
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.starts_with("application/json"));
    if is_json {
        return response;
    }
    let code = match status {
        // Our own 503s carry a JSON body; an empty one is the timeout layer.
        StatusCode::SERVICE_UNAVAILABLE | StatusCode::REQUEST_TIMEOUT => ErrorCode::Timeout,
        s => code_for_status(s),
    };
    let message = match code {
        ErrorCode::NotFound => "no such route".to_owned(),
        ErrorCode::MethodNotAllowed => "method not allowed on this route".to_owned(),
        ErrorCode::Timeout => "the request took too long".to_owned(),
        ErrorCode::PayloadTooLarge => "the request body is too large".to_owned(),
        _ => status.canonical_reason().unwrap_or("error").to_owned(),
    };
    let (mut parts, _) = response.into_parts();
    parts.headers.remove(header::CONTENT_LENGTH);
    parts.headers.insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("application/json"),
    );
    let body = serde_json::to_vec(&ErrorBody::new(code, message)).expect("error body serialises");
    Response::from_parts(parts, Body::from(body))
}

/// Refuses compressed request bodies (`Content-Encoding` other than
/// `identity`) before anything reads them: no route decodes them, so a
/// gzip or zstd body would otherwise be parsed as garbage and answered
/// with a misleading `invalid_json`; refusing also rules out
/// decompression bombs by construction.
async fn refuse_encoded_bodies(request: Request, next: Next) -> Response {
    let encoded = request
        .headers()
        .get_all(header::CONTENT_ENCODING)
        .iter()
        .any(|v| !v.as_bytes().eq_ignore_ascii_case(b"identity"));
    if encoded {
        // Read and drop up to 1 MiB of the body first: answering before
        // reading makes the server close the connection while the client
        // is still sending, and the client sees a broken pipe instead of
        // this answer. Compressed bytes are only counted, never inflated.
        let _ = axum::body::to_bytes(request.into_body(), 1 << 20).await;
        return ApiError::new(
            ErrorCode::UnsupportedMediaType,
            "compressed request bodies (Content-Encoding) are not accepted; send the body as it is",
        )
        .into_response();
    }
    next.run(request).await
}

async fn fallback() -> ApiError {
    ApiError::new(ErrorCode::NotFound, "no such route")
}

async fn method_not_allowed() -> ApiError {
    ApiError::new(
        ErrorCode::MethodNotAllowed,
        "method not allowed on this route",
    )
}

/// The `/v1` routes and their OpenAPI description. Routes that stream for
/// as long as a job runs (SSE, delta stream) get no request timeout.
pub fn api_routes(state: &AppState) -> OpenApiRouter<AppState> {
    let bounded = OpenApiRouter::new()
        .merge(trees::routes())
        .merge(jobs::routes())
        .layer(middleware::from_fn_with_state(state.clone(), time_limit));
    let streaming = OpenApiRouter::new()
        .merge(events::routes())
        .merge(stream::routes());
    bounded
        .merge(streaming)
        .layer(middleware::from_fn_with_state(state.clone(), authenticate))
}

/// Bounds a request by `--request-timeout` (503 `timeout`), except a tree
/// upload's body: an upload may take as long as its body keeps arriving
/// above `--min-body-rate` (the slow-body guard) and under
/// `--max-upload-bytes`, and the upload handler bounds the work that
/// follows the body by the same timeout ([`trees::post`]).
async fn time_limit(State(state): State<AppState>, request: Request, next: Next) -> Response {
    if request.method() == Method::POST && request.uri().path() == "/v1/trees" {
        return next.run(request).await;
    }
    match tokio::time::timeout(state.request_timeout(), next.run(request)).await {
        Ok(response) => response,
        Err(_) => timed_out().into_response(),
    }
}

/// The answer to a request that took longer than `--request-timeout`.
pub fn timed_out() -> ApiError {
    ApiError::new(ErrorCode::Timeout, "the request took too long")
}

/// The whole application: `/v1` (unless this is a worker-only process),
/// health, metrics and the OpenAPI document.
pub fn router(state: AppState) -> Router {
    let mut app = OpenApiRouter::new();
    if state.settings().role.serves_api() {
        app = app.merge(api_routes(&state));
    }
    let (mut app, _) = app.merge(health::routes()).split_for_parts();
    if state.settings().role.serves_api() {
        app = app.merge(web::routes(&state));
    }
    let cors = cors(state.settings());
    let body_limits = slow_body::Limits {
        idle: Duration::from_secs(state.settings().header_read_timeout.max(1)),
        grace: Duration::from_secs(state.settings().header_read_timeout.max(1)),
        min_rate: state.settings().min_body_rate,
    };
    app.fallback(fallback)
        .method_not_allowed_fallback(method_not_allowed)
        .layer(middleware::from_fn(refuse_encoded_bodies))
        .layer(middleware::from_fn(linger::layer))
        .layer(middleware::from_fn(move |request: Request, next: Next| {
            slow_body::layer(body_limits, request, next)
        }))
        .layer(middleware::from_fn_with_state(state.clone(), track))
        .layer(middleware::from_fn(uniform_errors))
        .layer(cors)
        .with_state(state)
}

fn cors(settings: &Settings) -> tower_http::cors::CorsLayer {
    use tower_http::cors::{AllowOrigin, CorsLayer};
    let origins = &settings.cors_origins;
    let allow = if origins.iter().any(|o| o == "*") {
        AllowOrigin::any()
    } else {
        AllowOrigin::list(
            origins
                .iter()
                .filter_map(|o| HeaderValue::from_str(o.trim()).ok()),
        )
    };
    CorsLayer::new()
        .allow_origin(allow)
        .allow_methods([Method::GET, Method::POST, Method::DELETE])
        .allow_headers([
            header::AUTHORIZATION,
            header::CONTENT_TYPE,
            header::RANGE,
            header::IF_NONE_MATCH,
            header::HeaderName::from_static("idempotency-key"),
        ])
        .expose_headers([
            header::LOCATION,
            header::RETRY_AFTER,
            header::ETAG,
            header::CONTENT_RANGE,
        ])
}

/// The runner `settings` ask for: the test runner when `--test-runner` is
/// set (tests only), the pipeline otherwise.
pub fn runner_for(settings: &Settings) -> anyhow::Result<Arc<dyn Runner>> {
    match &settings.test_runner {
        Some(spec) => {
            tracing::warn!(spec, "using the TEST runner: jobs produce synthetic frames");
            Ok(Arc::new(
                crate::jobs::testing::TestRunner::from_spec(spec).map_err(anyhow::Error::msg)?,
            ))
        }
        None => Ok(crate::pipeline::default_runner()),
    }
}

/// Runs the service on `listener` until `shutdown` resolves, with the
/// runner `settings` select.
pub async fn serve(
    settings: Settings,
    listener: tokio::net::TcpListener,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> anyhow::Result<()> {
    let runner = runner_for(&settings)?;
    let state = AppState::new(settings, runner).await?;
    serve_state(state, listener, shutdown).await
}

/// Runs the service with a prepared state (tests inject their runner
/// through [`AppState::new`]).
pub async fn serve_state(
    state: AppState,
    listener: tokio::net::TcpListener,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> anyhow::Result<()> {
    use hyper_util::rt::{TokioIo, TokioTimer};
    use hyper_util::server::graceful::GracefulShutdown;
    use tower::ServiceExt;

    let settings = state.services.settings.clone();
    let pool = settings
        .role
        .runs_workers()
        .then(|| crate::jobs::worker::Pool::start(state.services.clone()));
    let sweeper = tokio::spawn(crate::jobs::retention::sweep_loop(state.services.clone()));
    let app = router(state.clone());
    let mut http = hyper::server::conn::http1::Builder::new();
    http.timer(TokioTimer::new())
        .header_read_timeout(Duration::from_secs(settings.header_read_timeout.max(1)))
        // A strict cap on the request head: hyper's default (about 400 KiB)
        // only bounds the read buffer, and a head that arrives in one large
        // read could still be accepted (a flaky hostile test showed a
        // 512 KiB header answered 200). 64 KiB is far above any real
        // request's headers.
        .max_buf_size(MAX_HEAD_BYTES);
    let graceful = GracefulShutdown::new();
    tokio::pin!(shutdown);
    loop {
        tokio::select! {
            accepted = listener.accept() => {
                let (stream, _) = match accepted {
                    Ok(c) => c,
                    Err(e) => {
                        tracing::warn!(error = %e, "accept failed");
                        tokio::time::sleep(Duration::from_millis(50)).await;
                        continue;
                    }
                };
                let _ = stream.set_nodelay(true);
                let service = app
                    .clone()
                    .map_request(|r: axum::http::Request<hyper::body::Incoming>| r.map(Body::new));
                let connection = http.serve_connection(
                    TokioIo::new(stream),
                    hyper_util::service::TowerToHyperService::new(service),
                );
                let connection = graceful.watch(connection);
                tokio::spawn(async move {
                    if let Err(e) = connection.await {
                        tracing::debug!(error = %e, "connection ended with an error");
                    }
                });
            }
            () = &mut shutdown => break,
        }
    }
    drop(listener);
    sweeper.abort();
    tracing::info!("shutting down: no new connections");
    state.begin_shutdown();
    let grace = Duration::from_secs(settings.shutdown_grace);
    let drain_workers = async {
        if let Some(pool) = pool {
            pool.shutdown(grace).await;
        }
    };
    let drain_http = async {
        if tokio::time::timeout(grace + Duration::from_secs(1), graceful.shutdown())
            .await
            .is_err()
        {
            tracing::warn!("connections still open after the grace period; closing");
        }
    };
    tokio::join!(drain_workers, drain_http);
    tracing::info!("shut down");
    Ok(())
}

/// Resolves on SIGTERM or Ctrl-C.
pub async fn shutdown_signal() {
    let ctrl_c = async {
        let _ = tokio::signal::ctrl_c().await;
    };
    #[cfg(unix)]
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    #[cfg(not(unix))]
    let term = std::future::pending::<()>();
    tokio::select! {
        () = ctrl_c => {},
        () = term => {},
    }
}
