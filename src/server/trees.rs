//! `/v1/trees`: upload, generate, list, fetch and delete trees.
//!
//! Uploads are **streamed to a temporary file** under the data directory
//! with a running byte count (413 as soon as the limit is passed; a
//! `Content-Length` over the limit is refused before reading anything), so
//! a large or endless body never sits in memory. The file is then parsed,
//! analysed and exported on a blocking thread, and four blobs are stored
//! before the row that names them: the original upload, our tree JSON, the
//! full analysis JSON and our GLB export (served with an ETag).

use std::path::Path as FsPath;
use std::sync::Arc;

use axum::Json;
use axum::body::Body;
use axum::extract::{Path, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Response};
use futures_util::StreamExt;
use serde::Deserialize;
use tokio::io::AsyncWriteExt;
use treemorph_analysis::{Analysis, AnalysisOptions};
use treemorph_api::ErrorCode;
use treemorph_api::trees::{GenerateRequest, PatternCounts, TreeInfo, TreePage, TreeStats};
use treemorph_tree::{Limits, Tree};
use utoipa::{IntoParams, ToSchema};
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::extract::{
    ApiJson, ApiQuery, decode_cursor, encode_cursor, media_type, page_limit, path_id,
};
use super::{AppState, Owner, blob};
use crate::error::ApiError;
use crate::files::{LoadError, TreeFileKind, tree_of_kind};
use crate::pipeline::InputTree;
use crate::store::trees::{DeleteTree, TreeRow, blob_prefix};
use crate::store::{new_id, now_ms};
use treemorph_import::ImportError;

/// The routes of this module.
pub fn routes() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(post, list))
        .routes(routes!(generate))
        .routes(routes!(get, delete))
        .routes(routes!(model_glb))
        .routes(routes!(tree_json))
        .routes(routes!(analysis))
}

/// Query of `POST /v1/trees`.
#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
#[serde(deny_unknown_fields)]
pub struct UploadQuery {
    /// A name for people (1 to 256 bytes; default `tree`).
    #[param(min_length = 1, max_length = 256)]
    pub name: Option<String>,
}

/// Query of the list routes.
#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
#[serde(deny_unknown_fields)]
pub struct PageQuery {
    /// Page size, 1..=100 (default 20).
    #[param(minimum = 1, maximum = 100)]
    pub limit: Option<u32>,
    /// `next_cursor` of the previous page.
    #[param(pattern = "^[0-9a-f]{45}$")]
    pub cursor: Option<String>,
}

/// A JSON document (our tree format, glTF, the analysis, metrics): an
/// object whose schema is documented elsewhere.
#[derive(Debug)]
pub struct JsonDocument;

impl utoipa::PartialSchema for JsonDocument {
    fn schema() -> utoipa::openapi::RefOr<utoipa::openapi::schema::Schema> {
        utoipa::openapi::schema::Object::with_type(utoipa::openapi::schema::Type::Object).into()
    }
}

impl ToSchema for JsonDocument {}

/// A tree document (`application/vnd.treemorph.tree+json`): the OpenAPI
/// document names its required top level; `api/schemas/tree.schema.json`
/// is the full schema, and the server checks far more than a schema can
/// say (one root, no cycles, limits), answering `invalid_tree`.
#[derive(Debug)]
pub struct TreeDocument;

impl utoipa::PartialSchema for TreeDocument {
    fn schema() -> utoipa::openapi::RefOr<utoipa::openapi::schema::Schema> {
        use utoipa::openapi::schema::{ArrayBuilder, Object, ObjectBuilder, Type};
        ObjectBuilder::new()
            .schema_type(Type::Object)
            .description(Some(
                "A tree in our JSON format; the full schema is api/schemas/tree.schema.json",
            ))
            .property(
                "format",
                ObjectBuilder::new()
                    .schema_type(Type::String)
                    .enum_values(Some(["treemorph.tree/1"])),
            )
            .property(
                "nodes",
                ArrayBuilder::new()
                    .items(Object::with_type(Type::Object))
                    .min_items(Some(1)),
            )
            .required("format")
            .required("nodes")
            .into()
    }
}

impl ToSchema for TreeDocument {}

/// A glTF 2.0 JSON document (`model/gltf+json`): an object with `asset`
/// (the glTF schema is the Khronos one; the importer answers
/// `invalid_gltf` or `unsupported_gltf` for the rest).
#[derive(Debug)]
pub struct GltfDocument;

impl utoipa::PartialSchema for GltfDocument {
    fn schema() -> utoipa::openapi::RefOr<utoipa::openapi::schema::Schema> {
        use utoipa::openapi::schema::{Object, ObjectBuilder, Type};
        ObjectBuilder::new()
            .schema_type(Type::Object)
            .description(Some("A glTF 2.0 document with embedded data: URIs"))
            .property("asset", Object::with_type(Type::Object))
            .required("asset")
            .into()
    }
}

impl ToSchema for GltfDocument {}

/// Everything derived from an input tree, ready to store.
struct Prepared {
    /// The parsed tree and its analysis, for the tree cache.
    input: Arc<InputTree>,
    original: Vec<u8>,
    tree_json: Vec<u8>,
    analysis_json: Vec<u8>,
    glb: Vec<u8>,
    stats: TreeStats,
}

fn prepare(tree: Tree, original: Vec<u8>) -> Result<Prepared, ApiError> {
    let analysis = Analysis::of(&tree, &AnalysisOptions::default()).map_err(|e| {
        ApiError::new(
            ErrorCode::InvalidTree,
            format!("cannot analyse the tree: {e}"),
        )
    })?;
    let summary = analysis.summary();
    let tree_stats = tree.stats();
    let glb = treemorph_gltf::export_glb(&tree, &treemorph_gltf::ExportOptions::default())
        .map_err(|e| ApiError::internal(format!("GLB export failed: {e}")))?;
    // The stored JSON reads back bit-exactly (a tested property of the
    // format), so the tree cached here is the tree a worker would load.
    let tree_json = treemorph_tree::json::to_vec(&tree);
    let analysis_json = analysis.to_json();
    Ok(Prepared {
        input: Arc::new(InputTree::with_analysis(tree, analysis)),
        original,
        tree_json,
        analysis_json,
        glb,
        stats: TreeStats {
            branches: tree_stats.branches as u32,
            chains: summary.chains as u32,
            chain_groups: summary.chain_groups as u32,
            leaves: tree_stats.leaves as u32,
            patterns: PatternCounts {
                alternate: summary.patterns.alternate as u32,
                opposite: summary.patterns.opposite as u32,
                whorled: summary.patterns.whorled as u32,
            },
            height: tree_stats.height,
        },
    })
}

async fn store(
    state: &AppState,
    owner: &Owner,
    name: String,
    format: &str,
    prepared: Prepared,
) -> Result<Response, ApiError> {
    let json_bytes = prepared.tree_json.len() as u64;
    let stored_bytes = [
        &prepared.original,
        &prepared.tree_json,
        &prepared.analysis_json,
        &prepared.glb,
    ]
    .map(|b| b.len() as u64)
    .iter()
    .sum::<u64>();
    super::quota::check(state, owner, stored_bytes).await?;
    let id = new_id();
    let prefix = blob_prefix(&id);
    let blobs = &state.services.blobs;
    // Four files written side by side, then made durable together before
    // the row that acknowledges the upload is committed.
    let keys =
        ["original", "tree.json", "analysis.json", "model.glb"].map(|f| format!("{prefix}/{f}"));
    futures_util::try_join!(
        blobs.put_deferred(&keys[0], prepared.original),
        blobs.put_deferred(&keys[1], prepared.tree_json),
        blobs.put_deferred(&keys[2], prepared.analysis_json),
        blobs.put_deferred(&keys[3], prepared.glb),
    )?;
    blobs.sync(keys.to_vec()).await?;
    let row = TreeRow {
        id: id.clone(),
        owner: owner.0.clone(),
        name,
        format: format.to_owned(),
        stats: prepared.stats,
        created_at: now_ms(),
        stored_bytes: i64::try_from(stored_bytes).unwrap_or(i64::MAX),
    };
    state.services.db.insert_tree(&row).await?;
    state.services.trees.insert(&id, prepared.input, json_bytes);
    Ok((
        StatusCode::CREATED,
        [(header::LOCATION, format!("/v1/trees/{id}"))],
        Json(row.info()),
    )
        .into_response())
}

/// Upload a tree.
///
/// The body is a GLB (`model/gltf-binary`), glTF JSON (`model/gltf+json`)
/// or a treemorph tree document (`application/vnd.treemorph.tree+json`).
/// The tree is analysed at once; its statistics are in the response.
#[utoipa::path(
    post,
    path = "/v1/trees",
    operation_id = "upload_tree",
    tag = "trees",
    params(UploadQuery),
    request_body(
        description = "The tree file",
        content(
            ([u8] = "model/gltf-binary"),
            (GltfDocument = "model/gltf+json"),
            (TreeDocument = "application/vnd.treemorph.tree+json"),
        )
    ),
    responses(
        (status = 201, description = "Stored and analysed", body = TreeInfo,
            headers(("Location" = String, description = "URL of the new tree"))),
        (status = 413, description = "Larger than the upload limit (`payload_too_large`)", body = treemorph_api::ErrorBody),
        (status = 415, description = "Not one of the accepted media types (`unsupported_media_type`)", body = treemorph_api::ErrorBody),
        (status = 422, description = "Not a valid tree (`invalid_tree`, `invalid_gltf`) or bad query (`invalid_request`)", body = treemorph_api::ErrorBody),
        (status = 507, description = "The upload would take the API key over its storage quota (`quota_exceeded`), or the server's storage is full (`insufficient_storage`)", body = treemorph_api::ErrorBody),
    )
)]
pub async fn post(
    State(state): State<AppState>,
    owner: Owner,
    ApiQuery(query): ApiQuery<UploadQuery>,
    headers: HeaderMap,
    body: Body,
) -> Result<Response, ApiError> {
    let declared = match media_type(&headers).as_deref() {
        Some("model/gltf-binary") => TreeFileKind::Glb,
        Some("model/gltf+json") => TreeFileKind::Gltf,
        Some(m) if m == treemorph_tree::json::MEDIA_TYPE => TreeFileKind::TreeJson,
        _ => {
            return Err(ApiError::new(
                ErrorCode::UnsupportedMediaType,
                format!(
                    "Content-Type must be model/gltf-binary, model/gltf+json or {}",
                    treemorph_tree::json::MEDIA_TYPE
                ),
            ));
        }
    };
    let name = query.name.unwrap_or_else(|| "tree".into());
    if name.is_empty() || name.len() > 256 {
        return Err(ApiError::invalid("name must be 1 to 256 bytes long"));
    }
    let spooled = spool(&state, &headers, body).await?;
    let timeout = state.request_timeout();
    tokio::time::timeout(timeout, import(&state, &owner, name, declared, spooled))
        .await
        .map_err(|_| super::timed_out())?
}

/// Parses, analyses and stores a spooled upload: the part of an upload
/// the request timeout bounds (its body is bounded by rate and size).
async fn import(
    state: &AppState,
    owner: &Owner,
    name: String,
    declared: TreeFileKind,
    spooled: tempfile::NamedTempFile,
) -> Result<Response, ApiError> {
    let prepared = tokio::task::spawn_blocking(move || -> Result<Prepared, ApiError> {
        let bytes = std::fs::read(spooled.path()).map_err(ApiError::internal)?;
        drop(spooled);
        let upload = FsPath::new("upload");
        let kind = match crate::files::sniff(&bytes) {
            // JSON declared as glTF is read as glTF even when broken or
            // without `asset` (which the sniffer would hand to the tree
            // JSON parser): the client learns what is wrong with its glTF.
            Some(TreeFileKind::TreeJson) if declared == TreeFileKind::Gltf => TreeFileKind::Gltf,
            Some(kind) => kind,
            None => {
                let unknown = LoadError::UnknownFormat {
                    path: upload.to_owned(),
                };
                return Err(load_error(unknown, declared));
            }
        };
        let tree = tree_of_kind(&bytes, kind, &Limits::default(), upload)
            .map_err(|e| load_error(e, declared))?;
        if kind != declared {
            return Err(ApiError::new(
                invalid_code(declared),
                format!(
                    "the body is {} but Content-Type says {}",
                    kind.media_type(),
                    declared.media_type()
                ),
            ));
        }
        prepare(tree, bytes)
    })
    .await
    .map_err(ApiError::internal)??;
    store(state, owner, name, declared.name(), prepared).await
}

fn invalid_code(declared: TreeFileKind) -> ErrorCode {
    match declared {
        TreeFileKind::TreeJson => ErrorCode::InvalidTree,
        TreeFileKind::Glb | TreeFileKind::Gltf => ErrorCode::InvalidGltf,
    }
}

fn load_error(e: LoadError, declared: TreeFileKind) -> ApiError {
    match e {
        LoadError::Io { .. } => ApiError::internal(e),
        LoadError::UnknownFormat { .. } => ApiError::new(
            invalid_code(declared),
            format!("the body is not a {}", declared.media_type()),
        ),
        LoadError::TreeJson { .. } => ApiError::new(ErrorCode::InvalidTree, e.to_string()),
        LoadError::Gltf { ref source, .. } => {
            let code = match source {
                ImportError::UnsupportedGltf(_) => ErrorCode::UnsupportedGltf,
                ImportError::TooLarge(_) => ErrorCode::TooLarge,
                ImportError::InvalidTree(_) => ErrorCode::InvalidTree,
                ImportError::Internal(_) | ImportError::InvalidOptions(_) => {
                    return ApiError::internal(e);
                }
                _ => ErrorCode::InvalidGltf,
            };
            // The message names the problem, not the server's temp path.
            ApiError::new(code, source.to_string())
        }
    }
}

/// Streams the body into a temporary file, counting bytes.
async fn spool(
    state: &AppState,
    headers: &HeaderMap,
    body: Body,
) -> Result<tempfile::NamedTempFile, ApiError> {
    let limit = state.settings().max_upload_bytes;
    let too_large = || {
        ApiError::new(
            ErrorCode::PayloadTooLarge,
            format!("uploads are limited to {limit} bytes"),
        )
    };
    let declared_len = headers
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok());
    if declared_len.is_some_and(|n| n > limit) {
        return Err(too_large());
    }
    let tmp = tempfile::NamedTempFile::new_in(state.settings().data_dir.join("tmp"))
        .map_err(ApiError::io)?;
    let mut file = tokio::fs::File::from_std(tmp.reopen().map_err(ApiError::io)?);
    let mut stream = body.into_data_stream();
    let mut total = 0u64;
    while let Some(chunk) = stream.next().await {
        let chunk = chunk.map_err(|e| match super::slow_body::is_too_slow(&e) {
            Some(slow) => ApiError::new(ErrorCode::BodyTooSlow, slow.to_string()),
            None => ApiError::invalid(format!("reading the body failed: {e}")),
        })?;
        total += chunk.len() as u64;
        if total > limit {
            return Err(too_large());
        }
        file.write_all(&chunk).await.map_err(ApiError::io)?;
    }
    file.flush().await.map_err(ApiError::io)?;
    if total == 0 {
        return Err(ApiError::new(
            invalid_code_for(headers),
            "the body is empty",
        ));
    }
    Ok(tmp)
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_documented_preset_pattern_names_every_preset() {
        let schema = serde_json::to_value(
            <treemorph_api::trees::GenerateRequest as utoipa::PartialSchema>::schema(),
        )
        .unwrap();
        let pattern = schema["properties"]["preset"]["pattern"].as_str().unwrap();
        let mut names: Vec<&str> = pattern
            .trim_start_matches("^(")
            .trim_end_matches(")$")
            .split('|')
            .collect();
        let mut presets: Vec<&str> = treemorph_generate::Preset::ALL
            .iter()
            .map(|p| p.name())
            .collect();
        names.sort_unstable();
        presets.sort_unstable();
        assert_eq!(names, presets);
    }
}

fn invalid_code_for(headers: &HeaderMap) -> ErrorCode {
    match media_type(headers).as_deref() {
        Some("model/gltf-binary" | "model/gltf+json") => ErrorCode::InvalidGltf,
        _ => ErrorCode::InvalidTree,
    }
}

/// Generate a procedural tree.
///
/// Lets the service be tried without any file: the preset names are those
/// of `treemorph generate --list`.
#[utoipa::path(
    post,
    path = "/v1/trees/generate",
    operation_id = "generate_tree",
    tag = "trees",
    request_body(content = GenerateRequest, content_type = "application/json"),
    responses(
        (status = 201, description = "Generated, stored and analysed", body = TreeInfo,
            headers(("Location" = String, description = "URL of the new tree"))),
        (status = 400, description = "Malformed JSON (`invalid_json`)", body = treemorph_api::ErrorBody),
        (status = 413, description = "Body too large (`payload_too_large`)", body = treemorph_api::ErrorBody),
        (status = 415, description = "Not `application/json` (`unsupported_media_type`)", body = treemorph_api::ErrorBody),
        (status = 422, description = "Unknown preset, bad size or unknown field (`invalid_request`)", body = treemorph_api::ErrorBody),
        (status = 507, description = "The tree would take the API key over its storage quota (`quota_exceeded`), or the server's storage is full (`insufficient_storage`)", body = treemorph_api::ErrorBody),
    )
)]
pub async fn generate(
    State(state): State<AppState>,
    owner: Owner,
    ApiJson(request): ApiJson<GenerateRequest>,
) -> Result<Response, ApiError> {
    use treemorph_generate::{GenerateOptions, Preset};
    let preset: Preset = request
        .preset
        .parse()
        .map_err(|e| ApiError::invalid(format!("preset: {e}")))?;
    let size = request.size.unwrap_or(GenerateOptions::DEFAULT_SIZE);
    let options = GenerateOptions::new(preset, request.seed).with_size(size);
    options
        .validate()
        .map_err(|e| ApiError::invalid(e.to_string()))?;
    let prepared = tokio::task::spawn_blocking(move || -> Result<Prepared, ApiError> {
        let tree =
            treemorph_generate::generate(&options).map_err(|e| ApiError::invalid(e.to_string()))?;
        let json = treemorph_tree::json::to_vec(&tree);
        prepare(tree, json)
    })
    .await
    .map_err(ApiError::internal)??;
    let name = format!("{}-{}", preset.name(), request.seed);
    store(&state, &owner, name, "generated", prepared).await
}

/// List trees, newest first.
#[utoipa::path(
    get,
    path = "/v1/trees",
    operation_id = "list_trees",
    tag = "trees",
    params(PageQuery),
    responses(
        (status = 200, description = "One page of trees", body = TreePage),
        (status = 422, description = "Bad limit or cursor (`invalid_request`)", body = treemorph_api::ErrorBody),
    )
)]
pub async fn list(
    State(state): State<AppState>,
    owner: Owner,
    ApiQuery(query): ApiQuery<PageQuery>,
) -> Result<Json<TreePage>, ApiError> {
    let limit = page_limit(query.limit)?;
    let after = query.cursor.as_deref().map(decode_cursor).transpose()?;
    let mut rows = state.services.db.list_trees(&owner.0, after, limit).await?;
    let next_cursor = if rows.len() > limit as usize {
        rows.truncate(limit as usize);
        rows.last().map(|r| encode_cursor(r.created_at, &r.id))
    } else {
        None
    };
    Ok(Json(TreePage {
        items: rows.iter().map(TreeRow::info).collect(),
        next_cursor,
    }))
}

async fn find(state: &AppState, owner: &Owner, id: &str) -> Result<TreeRow, ApiError> {
    path_id(id, "tree")?;
    state
        .services
        .db
        .tree(&owner.0, id)
        .await?
        .ok_or_else(|| ApiError::not_found("tree"))
}

/// Get a tree's metadata and statistics.
#[utoipa::path(
    get,
    path = "/v1/trees/{id}",
    operation_id = "get_tree",
    tag = "trees",
    params(("id" = String, Path, description = "Tree id")),
    responses(
        (status = 200, description = "The tree", body = TreeInfo),
        (status = 404, description = "No such tree (`not_found`)", body = treemorph_api::ErrorBody),
    )
)]
pub async fn get(
    State(state): State<AppState>,
    owner: Owner,
    Path(id): Path<String>,
) -> Result<Json<TreeInfo>, ApiError> {
    Ok(Json(find(&state, &owner, &id).await?.info()))
}

/// Serves one stored file of `owner`'s tree `id` (404 for another key's
/// tree or none), with ranges and ETags.
async fn serve_file(
    state: &AppState,
    owner: &Owner,
    id: &str,
    headers: &HeaderMap,
    name: &str,
    media_type: &'static str,
) -> Result<Response, ApiError> {
    find(state, owner, id).await?;
    let key = format!("{}/{name}", blob_prefix(id));
    blob::serve(&state.services.blobs, &key, media_type, headers, "tree").await
}

/// Download the tree as GLB (our export, with the tree embedded).
#[utoipa::path(
    get,
    path = "/v1/trees/{id}/model.glb",
    operation_id = "get_tree_glb",
    tag = "trees",
    params(
        ("id" = String, Path, description = "Tree id"),
        ("Range" = Option<String>, Header, description = "A single byte range"),
        ("If-None-Match" = Option<String>, Header, description = "ETag of a cached copy"),
    ),
    responses(
        (status = 200, description = "The GLB", content_type = "model/gltf-binary", body = [u8],
            headers(("ETag" = String, description = "Strong entity tag"))),
        (status = 206, description = "A byte range of the GLB", content_type = "model/gltf-binary", body = [u8]),
        (status = 304, description = "Not modified"),
        (status = 404, description = "No such tree (`not_found`)", body = treemorph_api::ErrorBody),
        (status = 416, description = "Bad range (`range_not_satisfiable`)", body = treemorph_api::ErrorBody),
    )
)]
pub async fn model_glb(
    State(state): State<AppState>,
    owner: Owner,
    Path(id): Path<String>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    serve_file(
        &state,
        &owner,
        &id,
        &headers,
        "model.glb",
        "model/gltf-binary",
    )
    .await
}

/// Download the tree in the treemorph tree format.
#[utoipa::path(
    get,
    path = "/v1/trees/{id}/tree.json",
    operation_id = "get_tree_json",
    tag = "trees",
    params(
        ("id" = String, Path, description = "Tree id"),
        ("Range" = Option<String>, Header, description = "A single byte range"),
        ("If-None-Match" = Option<String>, Header, description = "ETag of a cached copy"),
    ),
    responses(
        (status = 200, description = "The tree document", content_type = "application/vnd.treemorph.tree+json", body = JsonDocument),
        (status = 206, description = "A byte range of the document", content_type = "application/vnd.treemorph.tree+json", body = [u8]),
        (status = 304, description = "Not modified"),
        (status = 404, description = "No such tree (`not_found`)", body = treemorph_api::ErrorBody),
        (status = 416, description = "Bad range (`range_not_satisfiable`)", body = treemorph_api::ErrorBody),
    )
)]
pub async fn tree_json(
    State(state): State<AppState>,
    owner: Owner,
    Path(id): Path<String>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    serve_file(
        &state,
        &owner,
        &id,
        &headers,
        "tree.json",
        treemorph_tree::json::MEDIA_TYPE,
    )
    .await
}

/// Get the full skeleton-lobe analysis (chains, chain groups, BPTT, lobes).
#[utoipa::path(
    get,
    path = "/v1/trees/{id}/analysis",
    operation_id = "get_tree_analysis",
    tag = "trees",
    params(
        ("id" = String, Path, description = "Tree id"),
        ("Range" = Option<String>, Header, description = "A single byte range"),
        ("If-None-Match" = Option<String>, Header, description = "ETag of a cached copy"),
    ),
    responses(
        (status = 200, description = "The analysis", content_type = "application/json", body = JsonDocument),
        (status = 206, description = "A byte range of the analysis", content_type = "application/json", body = [u8]),
        (status = 304, description = "Not modified"),
        (status = 404, description = "No such tree (`not_found`)", body = treemorph_api::ErrorBody),
        (status = 416, description = "Bad range (`range_not_satisfiable`)", body = treemorph_api::ErrorBody),
    )
)]
pub async fn analysis(
    State(state): State<AppState>,
    owner: Owner,
    Path(id): Path<String>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    serve_file(
        &state,
        &owner,
        &id,
        &headers,
        "analysis.json",
        "application/json",
    )
    .await
}

/// Delete a tree (refused while a queued or running job uses it).
#[utoipa::path(
    delete,
    path = "/v1/trees/{id}",
    operation_id = "delete_tree",
    tag = "trees",
    params(("id" = String, Path, description = "Tree id")),
    responses(
        (status = 204, description = "Deleted"),
        (status = 404, description = "No such tree (`not_found`)", body = treemorph_api::ErrorBody),
        (status = 409, description = "A job that still exists uses the tree (`tree_in_use`); delete the job first", body = treemorph_api::ErrorBody),
    )
)]
pub async fn delete(
    State(state): State<AppState>,
    owner: Owner,
    Path(id): Path<String>,
) -> Result<StatusCode, ApiError> {
    path_id(&id, "tree")?;
    match state.services.db.delete_tree(&owner.0, &id).await? {
        DeleteTree::Deleted => {
            state.services.trees.remove(&id);
            if let Err(e) = state.services.blobs.delete_prefix(&blob_prefix(&id)).await {
                tracing::warn!(tree = %id, error = %e, "deleting a tree's blobs failed");
            }
            Ok(StatusCode::NO_CONTENT)
        }
        DeleteTree::InUse => Err(ApiError::new(
            ErrorCode::TreeInUse,
            "a job uses this tree (its frames at new instants are rendered from it); delete the job first, or wait for it to expire",
        )),
        DeleteTree::NotFound => Err(ApiError::not_found("tree")),
    }
}
