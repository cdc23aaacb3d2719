//! Wire types of the `/v1/jobs` resource: the requests that start morph and
//! sketch jobs, and the job document clients poll, stream and receive in
//! webhooks.
//!
//! Requests are strict (`deny_unknown_fields`): a misspelt option is a 422
//! naming the field, never silently ignored. Optional fields are added
//! rather than renamed, so old clients keep working.

use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use crate::ErrorCode;

/// `POST /v1/jobs`: a morph or a sketch job, tagged by `kind`.
///
/// Its OpenAPI schema is written by hand (see the `ToSchema` impl): the
/// derived one composes each variant's strict (`additionalProperties:
/// false`) object with the `kind` tag through `allOf`, which no document
/// can satisfy.
///
/// It is read by hand: serde reads a `kind`-tagged enum through a buffer
/// that forgets where a bad value was, so a wrong `options.schedule`
/// would be reported without its field. Each variant is read on its own,
/// and an error names its path.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum JobRequest {
    /// Morph one tree into another.
    Morph(MorphRequest),
    /// Animate a tree into a sketched crown silhouette.
    Sketch(SketchRequest),
}

impl<'de> Deserialize<'de> for JobRequest {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<JobRequest, D::Error> {
        use serde::de::Error;
        let serde_json::Value::Object(mut body) = Strict::deserialize(d)?.0 else {
            return Err(D::Error::custom("a job request is a JSON object"));
        };
        let kind = body
            .remove("kind")
            .ok_or_else(|| D::Error::missing_field("kind"))?;
        let body = serde_json::Value::Object(body);
        match kind.as_str() {
            Some("morph") => variant(body).map(JobRequest::Morph),
            Some("sketch") => variant(body).map(JobRequest::Sketch),
            Some(other) => Err(D::Error::unknown_variant(other, &["morph", "sketch"])),
            None => Err(D::Error::custom(format!(
                "`kind` must be \"morph\" or \"sketch\", got {kind}"
            ))),
        }
    }
}

/// Any JSON value, refusing a key given twice in one object (as the
/// derived readers do) at any depth: a job request is read into a value
/// first, and a plain `serde_json::Value` keeps the last of duplicates.
struct Strict(serde_json::Value);

impl<'de> Deserialize<'de> for Strict {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Strict, D::Error> {
        d.deserialize_any(StrictVisitor).map(Strict)
    }
}

struct StrictVisitor;

impl<'de> serde::de::Visitor<'de> for StrictVisitor {
    type Value = serde_json::Value;

    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("a JSON value")
    }

    fn visit_bool<E>(self, v: bool) -> Result<serde_json::Value, E> {
        Ok(v.into())
    }

    fn visit_i64<E>(self, v: i64) -> Result<serde_json::Value, E> {
        Ok(v.into())
    }

    fn visit_u64<E>(self, v: u64) -> Result<serde_json::Value, E> {
        Ok(v.into())
    }

    fn visit_f64<E>(self, v: f64) -> Result<serde_json::Value, E> {
        Ok(v.into())
    }

    fn visit_str<E>(self, v: &str) -> Result<serde_json::Value, E> {
        Ok(v.into())
    }

    fn visit_unit<E>(self) -> Result<serde_json::Value, E> {
        Ok(serde_json::Value::Null)
    }

    fn visit_seq<A: serde::de::SeqAccess<'de>>(
        self,
        mut seq: A,
    ) -> Result<serde_json::Value, A::Error> {
        let mut items = Vec::new();
        while let Some(Strict(v)) = seq.next_element()? {
            items.push(v);
        }
        Ok(serde_json::Value::Array(items))
    }

    fn visit_map<A: serde::de::MapAccess<'de>>(
        self,
        mut map: A,
    ) -> Result<serde_json::Value, A::Error> {
        use serde::de::Error;
        let mut out = serde_json::Map::new();
        while let Some(key) = map.next_key::<String>()? {
            if out.contains_key(&key) {
                return Err(A::Error::custom(format!("duplicate field `{key}`")));
            }
            let Strict(v) = map.next_value()?;
            out.insert(key, v);
        }
        Ok(serde_json::Value::Object(out))
    }
}

/// One variant of a job request, its errors prefixed with their path.
fn variant<T: serde::de::DeserializeOwned, E: serde::de::Error>(
    body: serde_json::Value,
) -> Result<T, E> {
    serde_path_to_error::deserialize(body).map_err(|e| {
        let path = e.path().to_string();
        let e = e.into_inner();
        if path == "." {
            E::custom(e)
        } else {
            E::custom(format!("`{path}`: {e}"))
        }
    })
}

impl utoipa::PartialSchema for JobRequest {
    fn schema() -> utoipa::openapi::RefOr<utoipa::openapi::schema::Schema> {
        use utoipa::openapi::RefOr;
        use utoipa::openapi::schema::{ObjectBuilder, OneOfBuilder, Schema, Type};
        fn tagged<T: utoipa::PartialSchema>(kind: &str) -> RefOr<Schema> {
            match T::schema() {
                RefOr::T(Schema::Object(mut object)) => {
                    let tag = ObjectBuilder::new()
                        .schema_type(Type::String)
                        .enum_values(Some([kind]))
                        .description(Some("The job kind"))
                        .build();
                    object.properties.insert("kind".into(), tag.into());
                    object.required.insert(0, "kind".into());
                    object.title = Some(kind.into());
                    RefOr::T(Schema::Object(object))
                }
                other => other,
            }
        }
        OneOfBuilder::new()
            .item(tagged::<MorphRequest>("morph"))
            .item(tagged::<SketchRequest>("sketch"))
            .description(Some("A morph or a sketch job, tagged by `kind`."))
            .into()
    }
}

impl ToSchema for JobRequest {
    fn schemas(
        schemas: &mut Vec<(
            String,
            utoipa::openapi::RefOr<utoipa::openapi::schema::Schema>,
        )>,
    ) {
        <MorphRequest as ToSchema>::schemas(schemas);
        <SketchRequest as ToSchema>::schemas(schemas);
    }
}

impl JobRequest {
    /// The job kind (`morph` or `sketch`).
    pub fn kind(&self) -> JobKind {
        match self {
            JobRequest::Morph(_) => JobKind::Morph,
            JobRequest::Sketch(_) => JobKind::Sketch,
        }
    }

    /// Number of frames requested.
    pub fn frames(&self) -> u32 {
        match self {
            JobRequest::Morph(r) => r.frames,
            JobRequest::Sketch(r) => r.frames,
        }
    }

    /// The ids of the trees the job reads.
    pub fn tree_ids(&self) -> Vec<&str> {
        match self {
            JobRequest::Morph(r) => vec![r.source.as_str(), r.target.as_str()],
            JobRequest::Sketch(r) => vec![r.tree.as_str()],
        }
    }

    /// Which outputs to produce.
    pub fn outputs(&self) -> &Outputs {
        match self {
            JobRequest::Morph(r) => &r.outputs,
            JobRequest::Sketch(r) => &r.outputs,
        }
    }

    /// The webhook URL, if any.
    pub fn callback_url(&self) -> Option<&str> {
        match self {
            JobRequest::Morph(r) => r.callback_url.as_deref(),
            JobRequest::Sketch(r) => r.callback_url.as_deref(),
        }
    }
}

/// The two kinds of job.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum JobKind {
    /// Tree-to-tree morph.
    Morph,
    /// Tree-to-sketched-crown animation.
    Sketch,
}

impl JobKind {
    /// `morph` or `sketch`.
    pub fn as_str(self) -> &'static str {
        match self {
            JobKind::Morph => "morph",
            JobKind::Sketch => "sketch",
        }
    }
}

/// Which outputs a job produces (all by default).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(default, deny_unknown_fields)]
pub struct Outputs {
    /// One GLB per frame (`/v1/jobs/{id}/frames/{n}.glb`). Default true.
    pub glb: bool,
    /// One animated GLB of the whole sequence (`animation.glb`). Default
    /// true.
    pub animated: bool,
    /// The binary delta stream (`/v1/jobs/{id}/stream`). Default true.
    pub delta: bool,
}

impl Default for Outputs {
    fn default() -> Self {
        Outputs {
            glb: true,
            animated: true,
            delta: true,
        }
    }
}

/// A morph job: `source` grows, wilts, splits and merges into `target`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct MorphRequest {
    /// Id of the tree at t = 0.
    pub source: String,
    /// Id of the tree at t = 1.
    pub target: String,
    /// Number of frames, including both ends (2..=600 by default).
    #[schema(minimum = 2, maximum = 600)]
    #[serde(deserialize_with = "crate::int::u32")]
    pub frames: u32,
    /// Morph options.
    #[serde(default)]
    pub options: MorphJobOptions,
    /// Which outputs to produce.
    #[serde(default)]
    pub outputs: Outputs,
    /// URL that receives the job document when the job ends (Standard
    /// Webhooks signature).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub callback_url: Option<String>,
}

/// How chains of the two trees are matched.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, ToSchema, clap::ValueEnum,
)]
#[serde(rename_all = "snake_case")]
pub enum Matching {
    /// A chain may correspond to several chains (split/merge). Default.
    #[default]
    OneToMany,
    /// Each chain corresponds to at most one chain (grow/wilt the rest).
    OneToOne,
}

/// How leaves are assigned between the trees.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, ToSchema, clap::ValueEnum,
)]
#[serde(rename_all = "snake_case")]
pub enum LeafAssignment {
    /// Nearest-first greedy assignment. Default.
    #[default]
    Greedy,
    /// Random assignment (seeded, reproducible).
    Random,
}

/// Options of a morph job.
// This struct is the one definition of a morph job option: serde makes it
// the JSON of `POST /v1/jobs`, utoipa its OpenAPI schema, and clap the flags
// of `treemorph morph` and `treemorph client morph` (flattened into both);
// `treemorph_pipeline::JobSpec::parse` maps it to the pipeline. A new option
// is a new field here plus its line in that mapping.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, ToSchema, clap::Args)]
#[serde(default, deny_unknown_fields)]
pub struct MorphJobOptions {
    /// Chain matching: one-to-many (splits and merges; default) or
    /// one-to-one (the blending baseline: surplus chains grow or wilt).
    #[arg(long, value_enum, default_value_t)]
    pub matching: Matching,
    /// Leaf assignment: greedy on matched chains (default) or random with
    /// straight-line positions (the baseline that leaves leaves floating).
    #[arg(long, value_enum, default_value_t)]
    pub leaves: LeafAssignment,
    /// Whether split and merge copies use the paper's slow-down
    /// coefficient (copies part from the tips first rather than all along
    /// their length at once). Default `true`; `--no-slow-down` on the
    /// command line.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[arg(
        long = "no-slow-down",
        help = "Turn the slow-down coefficient off: split and merge copies part all along \
                their length at once instead of from the tips first",
        num_args = 0,
        default_missing_value = "false",
        value_parser = clap::value_parser!(bool)
    )]
    pub slow_down: Option<bool>,
    /// Keyframes of `animation.glb` (2 to `frames`): with `animation:
    /// keyframes`, its morph targets (default 24, or `frames` when
    /// fewer); with `basis`, the frames sampled for its weights (default
    /// all, at most 120).
    #[serde(
        skip_serializing_if = "Option::is_none",
        deserialize_with = "crate::int::opt_u32"
    )]
    #[arg(long)]
    pub keyframes: Option<u32>,
    /// Encoding of `animation.glb`'s morph targets: float (core glTF,
    /// plays everywhere; default), quantized (`KHR_mesh_quantization`,
    /// about half the size) or meshopt (`EXT_meshopt_compression`, about a
    /// sixth).
    #[arg(long, value_enum, default_value_t)]
    pub animation_encoding: AnimationEncoding,
    /// What `animation.glb`'s morph targets are: `basis` (default; at
    /// most 16 targets spanning the motion, one weight key per frame) or
    /// `keyframes` (one target per keyframe, the format before `basis`).
    #[arg(long, value_enum, default_value_t)]
    pub animation: AnimationKind,
    /// Most joints of a `skinned` animation besides its root (default
    /// 256, what game engines play vegetation with; 0: one joint per
    /// chain). Chains that move most nearly as their parent merge into it first.
    #[serde(
        skip_serializing_if = "Option::is_none",
        deserialize_with = "crate::int::opt_u32"
    )]
    #[arg(long)]
    pub skeleton_joints: Option<u32>,
    /// When each operation happens: `staged` (default; first shed, then
    /// reshape, then grow, parents before their twigs, growth from the
    /// tip) or `linear` (every operation on one clock over the whole
    /// morph, growth scaling about its junction).
    #[arg(long, value_enum, default_value_t)]
    pub schedule: ScheduleKind,
    /// `staged` only: how far the starts of a phase's windows spread, as a
    /// fraction of the phase, 0 to 0.9 (default 0.3: the deepest twigs
    /// start 30 % of a phase after the trunk).
    #[serde(skip_serializing_if = "Option::is_none")]
    #[arg(long)]
    pub stagger: Option<f32>,
    /// `staged` only: the fraction of each window spent accelerating, and
    /// as much decelerating, 0 to 0.5 (default 0.25; 0 is constant speed).
    #[serde(skip_serializing_if = "Option::is_none")]
    #[arg(long)]
    pub easing: Option<f32>,
    /// `staged` only: whether branches that would still pass through one
    /// another mid-morph are shed and regrown instead of blended (their
    /// chains leave the matching). Default `true`; `false` keeps every
    /// match and lets them cross. `--no-untangle` on the command line.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[arg(
        long = "no-untangle",
        help = "Keep every chain match, even those whose branches pass through one another \
                mid-morph, instead of shedding and regrowing them (staged only)",
        num_args = 0,
        default_missing_value = "false",
        value_parser = clap::value_parser!(bool)
    )]
    pub untangle: Option<bool>,
}

/// When the operations of a morph or a sketch happen.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, ToSchema, clap::ValueEnum,
)]
#[serde(rename_all = "snake_case")]
pub enum ScheduleKind {
    /// Shed, reshape, (in a morph) grow; parents lead; growth from the
    /// tip. Default.
    #[default]
    Staged,
    /// One clock for everything (the morph before schedules).
    Linear,
}

/// A sketch job: `tree` is animated into the crown `sketch` drawn from
/// `view`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct SketchRequest {
    /// Id of the tree to animate.
    pub tree: String,
    /// The camera the sketch was drawn from.
    pub view: View,
    /// The drawn silhouette.
    pub sketch: SketchInput,
    /// Number of frames, including both ends (2..=600 by default).
    #[schema(minimum = 2, maximum = 600)]
    #[serde(deserialize_with = "crate::int::u32")]
    pub frames: u32,
    /// Sketch options.
    #[serde(default)]
    pub options: SketchJobOptions,
    /// Which outputs to produce.
    #[serde(default)]
    pub outputs: Outputs,
    /// URL that receives the job document when the job ends.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub callback_url: Option<String>,
}

/// A camera: perspective (`fov_deg`) or orthographic (`ortho_height`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct View {
    /// Eye position (metres).
    #[schema(schema_with = vec3)]
    pub eye: [f32; 3],
    /// Point looked at (metres).
    #[schema(schema_with = vec3)]
    pub target: [f32; 3],
    /// Up direction.
    #[schema(schema_with = vec3)]
    pub up: [f32; 3],
    /// Vertical field of view in degrees (perspective camera).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fov_deg: Option<f32>,
    /// Height of the view volume in metres (orthographic camera).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ortho_height: Option<f32>,
    /// Width / height of the screen the sketch was drawn on (default 1):
    /// the screen spans `aspect` times its height horizontally, still
    /// mapped to x in [-1, 1].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schema(exclusive_minimum = 0.0)]
    pub aspect: Option<f32>,
}

/// A sketched polyline in normalised device coordinates ([-1, 1]², y up).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct SketchInput {
    /// The points of the stroke (at least 3).
    #[schema(schema_with = points)]
    pub points: Vec<[f32; 2]>,
    /// Whether the stroke is a closed outline.
    #[serde(default)]
    pub closed: bool,
}

fn numbers(n: usize) -> utoipa::openapi::schema::ArrayBuilder {
    use utoipa::openapi::schema::{ArrayBuilder, ObjectBuilder, Type};
    ArrayBuilder::new()
        .items(ObjectBuilder::new().schema_type(Type::Number).format(Some(
            utoipa::openapi::SchemaFormat::KnownFormat(utoipa::openapi::KnownFormat::Float),
        )))
        .min_items(Some(n))
        .max_items(Some(n))
}

fn vec3() -> utoipa::openapi::schema::Array {
    numbers(3).build()
}

fn points() -> utoipa::openapi::schema::Array {
    utoipa::openapi::schema::ArrayBuilder::new()
        .items(numbers(2))
        .min_items(Some(3))
        .build()
}

/// How the crown is deformed.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, ToSchema, clap::ValueEnum,
)]
#[serde(rename_all = "snake_case")]
pub enum SketchMethod {
    /// The multiscale cage tree (MCT). Default.
    #[default]
    Multiscale,
    /// One cage around the whole crown.
    SingleCage,
}

/// What `animation.glb`'s morph targets are.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, ToSchema, clap::ValueEnum,
)]
#[serde(rename_all = "snake_case")]
pub enum AnimationKind {
    /// The motion's principal displacements: at most 16 morph targets,
    /// the fewest that keep every vertex of every sampled frame within
    /// 0.5 % of the tree's height, and one weight key per sampled frame
    /// (`keyframes` sets how many; default all, at most 120). Leaves and
    /// bark change material in a staggered dissolve. Leaves are
    /// alpha-masked quads, whose outline changes with their texture.
    /// Default.
    #[default]
    Basis,
    /// One morph target per keyframe (`keyframes`, default 24): the
    /// file's size grows with the keyframe count. Leaves are 12-point
    /// outlines that morph between a leaf's two shapes.
    Keyframes,
    /// A skeleton that follows the branch hierarchy (at most
    /// `skeleton_joints` joints), with per-joint translation, rotation
    /// and scale at every sampled frame; bark and leaves are bound to
    /// their chain's joint. What the joints cannot express stays as the
    /// fewest morph targets (at most 16) that keep every vertex within
    /// 1 % of the tree's height (`metrics.json` reports the error
    /// reached); leaves (quads) and bark dissolve as in `basis`.
    /// For game engines.
    Skinned,
}

/// How `animation.glb` stores its morph targets.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, ToSchema, clap::ValueEnum,
)]
#[serde(rename_all = "snake_case")]
pub enum AnimationEncoding {
    /// 32-bit floats: core glTF, plays everywhere (largest file).
    #[default]
    Float,
    /// 16-bit positions and 8-bit normals (`KHR_mesh_quantization`):
    /// about half the size.
    Quantized,
    /// Quantised and compressed (`EXT_meshopt_compression`): about a sixth
    /// of the float size; needs a viewer with the meshopt decoder.
    Meshopt,
}

/// What the sketch is fitted to.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, ToSchema, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum SketchFit {
    /// Fit the crown (leaves and outer branches) to the sketch.
    Crown,
}

/// Options of a sketch job.
// Like `MorphJobOptions`: the one definition of the JSON fields, their
// OpenAPI schema and the command-line flags of `treemorph sketch` and
// `treemorph client sketch`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, ToSchema, clap::Args)]
#[serde(default, deny_unknown_fields)]
pub struct SketchJobOptions {
    /// Deformation method: the multiscale cage tree (default) or one
    /// global cage (the baseline).
    #[arg(long, value_enum, default_value_t)]
    pub method: SketchMethod,
    /// What the sketch is fitted to; the pipeline's default when absent
    /// (on the command line, a sketch file's `"fit"` applies too).
    #[serde(skip_serializing_if = "Option::is_none")]
    #[arg(long, value_enum)]
    pub fit: Option<SketchFit>,
    /// Keyframes of `animation.glb` (2 to `frames`): with `animation:
    /// keyframes`, its morph targets (default 24, or `frames` when
    /// fewer); with `basis`, the frames sampled for its weights (default
    /// all, at most 120).
    #[serde(
        skip_serializing_if = "Option::is_none",
        deserialize_with = "crate::int::opt_u32"
    )]
    #[arg(long)]
    pub keyframes: Option<u32>,
    /// Encoding of `animation.glb`'s morph targets: float (default),
    /// quantized or meshopt (see the morph options).
    #[arg(long, value_enum, default_value_t)]
    pub animation_encoding: AnimationEncoding,
    /// What `animation.glb`'s morph targets are: `basis` (default) or
    /// `keyframes` (see the morph options).
    #[arg(long, value_enum, default_value_t)]
    pub animation: AnimationKind,
    /// Most joints of a `skinned` animation besides its root (default
    /// 256, what game engines play vegetation with; 0: one joint per
    /// chain). Chains that move most nearly as their parent merge into it first.
    #[serde(
        skip_serializing_if = "Option::is_none",
        deserialize_with = "crate::int::opt_u32"
    )]
    #[arg(long)]
    pub skeleton_joints: Option<u32>,
    /// When each branch moves: `staged` (default; pruned branches wilt
    /// first, then every branch turns toward its sketched pose, parents
    /// before their twigs, each eased) or `linear` (every branch on one
    /// clock over the whole animation). Either way branches turn about
    /// their joints.
    #[arg(long, value_enum, default_value_t)]
    pub schedule: ScheduleKind,
    /// `staged` only: how far the starts of the branches' windows spread,
    /// as a fraction of the animation, 0 to 0.9 (default 0.3: the deepest
    /// twigs start 30 % of it after the trunk).
    #[serde(skip_serializing_if = "Option::is_none")]
    #[arg(long)]
    pub stagger: Option<f32>,
    /// `staged` only: the fraction of each window spent accelerating, and
    /// as much decelerating, 0 to 0.5 (default 0.25; 0 is constant speed).
    #[serde(skip_serializing_if = "Option::is_none")]
    #[arg(long)]
    pub easing: Option<f32>,
}

/// A job's life cycle: `queued` → `running` → `succeeded` | `failed` |
/// `cancelled` (a queued job can be cancelled directly; a running job whose
/// attempt failed transiently goes back to `queued`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum JobStatus {
    /// Waiting for a worker.
    Queued,
    /// A worker holds the job's lease.
    Running,
    /// Finished; `result` is set.
    Succeeded,
    /// Finished with an error; `error` is set.
    Failed,
    /// Cancelled by the client.
    Cancelled,
}

impl JobStatus {
    /// Every status.
    pub const ALL: [JobStatus; 5] = [
        JobStatus::Queued,
        JobStatus::Running,
        JobStatus::Succeeded,
        JobStatus::Failed,
        JobStatus::Cancelled,
    ];

    /// The snake_case name.
    pub fn as_str(self) -> &'static str {
        match self {
            JobStatus::Queued => "queued",
            JobStatus::Running => "running",
            JobStatus::Succeeded => "succeeded",
            JobStatus::Failed => "failed",
            JobStatus::Cancelled => "cancelled",
        }
    }

    /// The status named `s`.
    pub fn parse(s: &str) -> Option<JobStatus> {
        JobStatus::ALL.into_iter().find(|st| st.as_str() == s)
    }

    /// Whether the job has ended.
    pub fn is_terminal(self) -> bool {
        matches!(
            self,
            JobStatus::Succeeded | JobStatus::Failed | JobStatus::Cancelled
        )
    }
}

/// A job's error.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct JobErrorInfo {
    /// Stable error code.
    pub code: ErrorCode,
    /// What went wrong.
    pub message: String,
}

/// Where a finished job's outputs are.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct JobLinks {
    /// The animated GLB (absent when not requested).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub animation: Option<String>,
    /// The complete delta stream (absent when not requested).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stream: Option<String>,
    /// The metrics document.
    pub metrics: String,
    /// URL template of per-frame GLBs: replace `{n}` by the 0-based index
    /// (absent when not requested).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frames: Option<String>,
    /// URL template of the frame at any instant, rendered on request:
    /// replace `{t}` by a number in [0, 1] (absent from servers older than
    /// this field).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame_at: Option<String>,
    /// URL template of the frame at any instant as a one-frame delta
    /// stream with the job's own stream header (what a player scrubbing
    /// between the stream's frames asks for): replace `{t}` by a number in
    /// [0, 1] (absent from servers older than this field).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stream_at: Option<String>,
}

/// A finished job's result.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct JobResult {
    /// Frames produced.
    pub frames: u32,
    /// Summary metrics reported by the pipeline.
    #[schema(value_type = Object)]
    pub metrics: serde_json::Value,
    /// Output URLs.
    pub links: JobLinks,
}

/// The job document (`GET /v1/jobs/{id}`, the `202` of `POST /v1/jobs`, and
/// the webhook body).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct JobInfo {
    /// The job's id.
    pub id: String,
    /// `morph` or `sketch`.
    pub kind: JobKind,
    /// Where the job is in its life cycle.
    pub status: JobStatus,
    /// Overall progress in [0, 1].
    pub progress: f32,
    /// Current stage (`loading`, `analysing`, `planning`, `frames`,
    /// `finishing`), absent before the first claim.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stage: Option<String>,
    /// Attempts started so far (1 after the first claim).
    pub attempt: u32,
    /// Frames requested.
    pub frames: u32,
    /// Frames published so far by the current attempt (their GLBs and
    /// stream records can be fetched).
    pub frames_ready: u32,
    /// Whether a cancellation was requested and not yet acted on.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub cancel_requested: bool,
    /// When the job was created (RFC 3339, UTC).
    pub created_at: String,
    /// When the job last changed (RFC 3339, UTC).
    pub updated_at: String,
    /// Set when `status` is `failed` (or `cancelled`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<JobErrorInfo>,
    /// Set when `status` is `succeeded`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub result: Option<JobResult>,
}

/// One page of jobs, newest first.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct JobPage {
    /// The jobs on this page.
    pub items: Vec<JobInfo>,
    /// Pass as `?cursor=` for the next page; absent on the last page.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub next_cursor: Option<String>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn morph_request_parses_with_defaults() {
        let r: JobRequest = serde_json::from_str(
            r#"{"kind": "morph", "source": "a", "target": "b", "frames": 10}"#,
        )
        .unwrap();
        let JobRequest::Morph(m) = &r else {
            panic!("not a morph")
        };
        assert_eq!(m.options, MorphJobOptions::default());
        assert_eq!(m.outputs, Outputs::default());
        assert_eq!(r.tree_ids(), ["a", "b"]);
        assert_eq!(r.kind(), JobKind::Morph);
    }

    #[test]
    fn unknown_fields_are_named() {
        let e = serde_json::from_str::<JobRequest>(
            r#"{"kind": "morph", "source": "a", "target": "b", "frames": 10, "frobnicate": 1}"#,
        )
        .unwrap_err();
        assert!(e.to_string().contains("frobnicate"), "{e}");
        let e = serde_json::from_str::<JobRequest>(
            r#"{"kind": "morph", "source": "a", "target": "b", "frames": 10, "options": {"matchin": "one_to_one"}}"#,
        )
        .unwrap_err();
        assert!(e.to_string().contains("matchin"), "{e}");
    }

    /// Regression: reading a job request through a JSON value once
    /// accepted a key given twice, keeping the last, where the derived
    /// reader refuses it.
    #[test]
    fn duplicate_keys_are_refused_at_any_depth() {
        for body in [
            r#"{"kind": "morph", "source": "a", "target": "b", "frames": 10, "frames": 11}"#,
            r#"{"kind": "morph", "source": "a", "target": "b", "frames": 10, "options": {"stagger": 0.1, "stagger": 0.2}}"#,
        ] {
            let e = serde_json::from_str::<JobRequest>(body).unwrap_err();
            assert!(e.to_string().contains("duplicate field"), "{e}");
        }
        let e = serde_json::from_str::<JobRequest>("[1]").unwrap_err();
        assert!(e.to_string().contains("object"), "{e}");
    }

    #[test]
    fn a_bad_value_is_named_by_its_path() {
        let e = serde_json::from_str::<JobRequest>(
            r#"{"kind": "morph", "source": "a", "target": "b", "frames": 10, "options": {"schedule": "eased"}}"#,
        )
        .unwrap_err();
        assert!(e.to_string().contains("options.schedule"), "{e}");
    }

    #[test]
    fn sketch_request_round_trips() {
        let json = serde_json::json!({
            "kind": "sketch", "tree": "t",
            "view": {"eye": [0, 1, 5], "target": [0, 1, 0], "up": [0, 1, 0], "fov_deg": 45},
            "sketch": {"points": [[0, 0], [1, 0], [0, 1]], "closed": true},
            "frames": 3, "options": {"method": "single_cage", "fit": "crown"},
            "outputs": {"glb": false}
        });
        let r: JobRequest = serde_json::from_value(json).unwrap();
        assert!(!r.outputs().glb && r.outputs().delta);
        let back: JobRequest = serde_json::from_value(serde_json::to_value(&r).unwrap()).unwrap();
        assert_eq!(back, r);
    }
}
