//! The OpenAPI 3.1 document, generated from the handlers' `#[utoipa::path]`
//! annotations and the wire types' `ToSchema` derives, served at
//! `/openapi.yaml` and committed as `openapi.yaml` at the repository root
//! (a test fails when the two differ; `UPDATE_OPENAPI=1 cargo test -p
//! treemorph --test it openapi` rewrites the file).
//!
//! Responses every `/v1` operation can give are added here rather than on
//! each handler: 401 `unauthorized` (when API keys are configured), 429
//! `rate_limited` (with `Retry-After`), 500 `internal` and 503
//! `unavailable`/`timeout`. `POST /v1/jobs` also documents 429
//! `queue_full`.

use std::sync::OnceLock;

use axum::http::{StatusCode, header};
use axum::response::IntoResponse;
use utoipa::OpenApi;
use utoipa::openapi::content::Content;
use utoipa::openapi::header::Header;
use utoipa::openapi::response::Response;
use utoipa::openapi::schema::{Object, Ref, Type};
use utoipa::openapi::security::{Http, HttpAuthScheme, SecurityRequirement, SecurityScheme};
use utoipa_axum::router::OpenApiRouter;

use super::AppState;

#[derive(OpenApi)]
#[openapi(
    info(
        title = "treemorph",
        description = "Morph leafy 3D trees into each other and animate them into sketched crowns. \
Every error is `{\"error\": {\"code\", \"message\"}}` with a stable snake_case code.",
        license(name = "MIT OR Apache-2.0")
    ),
    components(schemas(treemorph_api::ErrorBody, treemorph_api::ErrorCode)),
    tags(
        (name = "trees", description = "Upload, generate and inspect trees"),
        (name = "jobs", description = "Morph and sketch jobs, their progress and outputs"),
        (name = "operations", description = "Health, readiness, metrics and this document"),
    )
)]
struct ApiDoc;

fn error_response(description: &str) -> Response {
    let mut r = Response::new(description);
    r.content.insert(
        "application/json".into(),
        Content::new(Some(Ref::from_schema_name("ErrorBody"))).into(),
    );
    r
}

fn with_retry_after(mut r: Response) -> Response {
    r.headers.insert(
        "Retry-After".into(),
        Header::new(Object::with_type(Type::Integer)).into(),
    );
    r
}

/// Builds the document.
pub fn document() -> utoipa::openapi::OpenApi {
    let mut doc = OpenApiRouter::<AppState>::with_openapi(ApiDoc::openapi())
        .merge(super::trees::routes())
        .merge(super::jobs::routes())
        .merge(super::events::routes())
        .merge(super::stream::routes())
        .merge(super::health::routes())
        .into_openapi();
    doc.components
        .get_or_insert_with(Default::default)
        .add_security_scheme(
            "bearer",
            SecurityScheme::Http(Http::new(HttpAuthScheme::Bearer)),
        );
    doc.info.version = env!("CARGO_PKG_VERSION").into();
    for (path, item) in doc.paths.paths.iter_mut() {
        if !path.starts_with("/v1/") {
            continue;
        }
        for (op, is_post_job) in [
            (item.get.as_mut(), false),
            (item.post.as_mut(), path == "/v1/jobs"),
            (item.delete.as_mut(), false),
        ] {
            let Some(op) = op else { continue };
            let responses = &mut op.responses.responses;
            let mut add = |status: &str, r: Response| {
                responses.entry(status.into()).or_insert(r.into());
            };
            add(
                "401",
                error_response("A valid API key is required (`unauthorized`)"),
            );
            add(
                "429",
                with_retry_after(error_response(if is_post_job {
                    "Too many requests for this API key (`rate_limited`) or too many queued jobs (`queue_full`); retry after `Retry-After` seconds"
                } else {
                    "Too many requests for this API key (`rate_limited`); retry after `Retry-After` seconds"
                })),
            );
            add("500", error_response("Internal error (`internal`)"));
            add(
                "503",
                error_response(
                    "A dependency is unavailable (`unavailable`) or the request timed out (`timeout`)",
                ),
            );
            op.security = Some(vec![SecurityRequirement::new(
                "bearer",
                Vec::<String>::new(),
            )]);
        }
    }
    doc
}

/// The document as YAML (computed once).
pub fn yaml() -> &'static str {
    static YAML: OnceLock<String> = OnceLock::new();
    YAML.get_or_init(|| {
        document()
            .to_yaml()
            .expect("the OpenAPI document serialises")
    })
}

/// This document.
#[utoipa::path(
    get,
    path = "/openapi.yaml",
    operation_id = "openapi",
    tag = "operations",
    responses((status = 200, description = "The OpenAPI document", content_type = "application/yaml", body = super::trees::JsonDocument))
)]
pub async fn spec() -> impl IntoResponse {
    (
        StatusCode::OK,
        [(header::CONTENT_TYPE, "application/yaml")],
        yaml(),
    )
}
