//! `treemorph client`: a command-line client of the service's REST API
//! (`openapi.yaml`), for scripts and people.
//!
//! ```text
//! treemorph client upload FILE [--name N]             → prints the tree id
//! treemorph client generate --preset P [--seed S] [--size N] → prints the tree id
//! treemorph client morph A B --frames N [--wait] [-o DIR]   → prints the job id
//! treemorph client sketch TREE --sketch FILE [--wait] [-o DIR] → prints the job id
//! treemorph client status JOB
//! treemorph client watch JOB                           (progress from SSE)
//! treemorph client download JOB [--format …] -o DIR
//! treemorph client download JOB --t 0.5 -o DIR         (the frame at an instant)
//! treemorph client cancel JOB
//! treemorph client delete JOB                          (cancels first if it runs)
//! ```
//!
//! `--server URL` (`TREEMORPH_SERVER`, default `http://127.0.0.1:8080`)
//! and `--api-key KEY` (`TREEMORPH_API_KEY`, sent as `Authorization:
//! Bearer KEY`) apply to every subcommand; `--json` prints the server's
//! JSON document on stdout instead of the human summary.
//!
//! # Output
//! Ids go to stdout, alone on the first line, so `id=$(treemorph client
//! generate --preset maple)` works; summaries, progress and errors go to
//! stderr. `status` prints its summary on stdout (it is the answer);
//! `watch` prints the final status word; `download` prints the paths it
//! wrote. A server error is printed as `error: <code>: <message>`, with
//! the stable code of `treemorph_api::ErrorCode`.
//!
//! # Exit codes
//! Scripts can test these (the first three are those of every `treemorph`
//! command):
//!
//! | code | meaning |
//! |------|---------|
//! | 0 | success (`watch`, `--wait`: the job succeeded) |
//! | 1 | the job failed or was cancelled, the server failed (5xx), or a local write failed |
//! | 2 | the command line is wrong |
//! | 3 | invalid input: a local file is missing or invalid, or the server refused the request (4xx: `invalid_request`, `invalid_tree`, `invalid_sketch`, `job_finished`, `not_ready`, …) |
//! | 4 | not found: no such job or tree (`not_found`, `tree_not_found`) |
//! | 5 | the server is unreachable (connection refused, DNS, timeout) |
//! | 6 | unauthorized: the API key is missing or wrong |
//! | 7 | busy: rate limited or the queue is full (`rate_limited`, `queue_full`); retry later |
//!
//! The client runs on a current-thread tokio runtime; `watch` parses the
//! SSE stream itself ([`sse`]) and reconnects when the connection drops.

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Context, anyhow};
use reqwest::Method;
use reqwest::header::CONTENT_TYPE;
use treemorph_api::jobs::{JobInfo, JobRequest, JobStatus, MorphJobOptions, SketchJobOptions};
use treemorph_api::trees::{GenerateRequest, TreeInfo};

use super::job_args::{Format, morph_request, read_sketch_file, sketch_request};
use super::{EXIT_FAILURE, Failure};
use api::{Api, failure};
use download::DownloadFormat;

mod api;
mod download;
mod follow;
mod sse;

/// Exit code: no such job or tree (404).
pub const EXIT_NOT_FOUND: u8 = 4;
/// Exit code: the server cannot be reached.
pub const EXIT_UNREACHABLE: u8 = 5;
/// Exit code: the API key is missing or wrong (401).
pub const EXIT_UNAUTHORIZED: u8 = 6;
/// Exit code: rate limited or queue full (429); retry later.
pub const EXIT_BUSY: u8 = 7;

const AFTER_HELP: &str = "\
Examples:
  export TREEMORPH_SERVER=http://127.0.0.1:8080
  a=$(treemorph client generate --preset maple --seed 1)
  b=$(treemorph client upload shrub.glb)
  treemorph client morph \"$a\" \"$b\" --frames 48 -o out/
  treemorph client sketch \"$a\" --sketch examples/sketches/heart.json --wait

Exit codes:
  0  success (watch, --wait: the job succeeded)
  1  the job failed or was cancelled, the server failed (5xx), or writing a file failed
  2  the command line is wrong
  3  invalid input: a local file is missing or invalid, or the server refused
     the request (4xx such as invalid_request, invalid_tree, invalid_sketch)
  4  not found: no such job or tree (not_found, tree_not_found)
  5  the server is unreachable
  6  unauthorized: the API key is missing or wrong
  7  busy: rate_limited or queue_full; retry later

Server errors are printed as `error: <code>: <message>`.";

/// Arguments of `treemorph client`.
#[derive(Debug, clap::Args)]
#[command(after_help = AFTER_HELP)]
pub struct Args {
    /// Base URL of the treemorph service.
    #[arg(
        long,
        global = true,
        env = "TREEMORPH_SERVER",
        default_value = "http://127.0.0.1:8080"
    )]
    server: String,
    /// API key, sent as `Authorization: Bearer KEY`.
    #[arg(long, global = true, env = "TREEMORPH_API_KEY", hide_env_values = true)]
    api_key: Option<String>,
    /// Print the server's JSON document on stdout instead of a summary.
    #[arg(long, global = true)]
    json: bool,
    #[command(subcommand)]
    command: ClientCommand,
}

#[derive(Debug, clap::Subcommand)]
enum ClientCommand {
    /// Upload a tree file (GLB, glTF or treemorph JSON); prints its id.
    Upload(UploadArgs),
    /// Generate a procedural tree on the server; prints its id.
    Generate(GenerateArgs),
    /// Start a morph job between two stored trees; prints the job id.
    Morph(MorphArgs),
    /// Start a sketch job on a stored tree; prints the job id.
    Sketch(SketchArgs),
    /// Print a job's status, stage, progress and error.
    Status(JobArg),
    /// Follow a job's progress until it ends (exit 0 only if it succeeded).
    Watch(JobArg),
    /// Download a finished job's outputs into a directory.
    Download(DownloadArgs),
    /// Cancel a queued or running job (never deletes it).
    Cancel(JobArg),
    /// Delete a job and every output it stored; a queued or running job is
    /// cancelled first and deleted once it has stopped.
    Delete(JobArg),
}

/// `client upload`.
#[derive(Debug, clap::Args)]
struct UploadArgs {
    /// The tree file: GLB, glTF with embedded buffers, or treemorph JSON
    /// (recognised from its content, else its extension).
    file: PathBuf,
    /// A name for people [default: the file name without extension].
    #[arg(long)]
    name: Option<String>,
}

/// `client generate`.
#[derive(Debug, clap::Args)]
struct GenerateArgs {
    /// Tree preset (as `treemorph generate --list` prints them).
    #[arg(long)]
    preset: String,
    /// Random seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Number of branches [default: the server's, 5,000].
    #[arg(long)]
    size: Option<u32>,
}

/// Job options shared by `client morph` and `client sketch`.
#[derive(Debug, clap::Args)]
struct JobArgs {
    /// Number of frames (2–600 unless the server allows more).
    #[arg(long, default_value_t = 60)]
    frames: u32,
    /// Outputs the job produces (repeatable or comma-separated; default
    /// all). `-o DIR` downloads these.
    #[arg(long, value_enum, value_delimiter = ',')]
    format: Vec<Format>,
    /// URL that receives the job document when the job ends (webhook).
    #[arg(long)]
    callback_url: Option<String>,
    /// Idempotency key: retrying with the same key and request returns the
    /// same job instead of starting another.
    #[arg(long)]
    idempotency_key: Option<String>,
    /// Follow the job's progress until it ends; the exit code tells how it
    /// ended.
    #[arg(long)]
    wait: bool,
    /// Download the outputs into DIR once the job succeeded (implies
    /// --wait).
    #[arg(short, long, value_name = "DIR")]
    output: Option<PathBuf>,
}

/// `client morph`.
#[derive(Debug, clap::Args)]
struct MorphArgs {
    /// The source tree (t = 0): a tree id, or a GLB, glTF or treemorph JSON
    /// file, which is uploaded first.
    source: String,
    /// The target tree (t = 1): a tree id or a file, like SOURCE.
    target: String,
    #[command(flatten)]
    job: JobArgs,
    #[command(flatten)]
    options: MorphJobOptions,
}

/// `client sketch`.
#[derive(Debug, clap::Args)]
#[command(
    after_help = "SKETCH is the file `treemorph sketch` reads: {\"view\": {\"eye\", \"target\", \
\"up\", \"fov_deg\"}, \"points\": [[x, y], ...], \"closed\": true, \"fit\": \"crown\"} \
(e.g. examples/sketches/heart.json)."
)]
struct SketchArgs {
    /// The tree to animate: a tree id, or a GLB, glTF or treemorph JSON
    /// file, which is uploaded first.
    tree: String,
    /// The sketch file (view + sketch, as `treemorph sketch` reads it).
    #[arg(long)]
    sketch: PathBuf,
    #[command(flatten)]
    job: JobArgs,
    #[command(flatten)]
    options: SketchJobOptions,
}

/// A job id.
#[derive(Debug, clap::Args)]
struct JobArg {
    /// The job id (as `client morph` or `client sketch` printed it).
    job: String,
}

/// `client download`.
#[derive(Debug, clap::Args)]
struct DownloadArgs {
    /// The job id.
    job: String,
    /// What to download (repeatable or comma-separated; default all the
    /// job produced).
    #[arg(long, value_enum, value_delimiter = ',')]
    format: Vec<DownloadFormat>,
    /// Output directory (created if missing).
    #[arg(short, long, value_name = "DIR")]
    output: PathBuf,
    /// Wait for the job to end first.
    #[arg(long)]
    wait: bool,
    /// Download only the frame at this instant in [0, 1], rendered by the
    /// server on request, as `DIR/frame_at_T.glb`.
    #[arg(long = "t", value_name = "T", conflicts_with = "format")]
    t: Option<f32>,
}

/// Runs `treemorph client`.
pub(super) fn run(args: &Args) -> Result<(), Failure> {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    runtime.block_on(run_async(args))
}

async fn run_async(args: &Args) -> Result<(), Failure> {
    let api = Api::new(&args.server, args.api_key.clone())?;
    let json = args.json;
    match &args.command {
        ClientCommand::Upload(a) => upload(&api, a, json).await,
        ClientCommand::Generate(a) => generate(&api, a, json).await,
        ClientCommand::Morph(a) => {
            // The file (or id) is checked before anything is uploaded, so a
            // typo in the second name uploads nothing.
            let source = TreeRef::of(&a.source).await?;
            let target = TreeRef::of(&a.target).await?;
            let ids = (source.id(&api).await?, target.id(&api).await?);
            let request = morph_request(
                ids,
                a.job.frames,
                &a.options,
                &a.job.format,
                a.job.callback_url.clone(),
            );
            start_job(&api, request, &a.job, json).await
        }
        ClientCommand::Sketch(a) => {
            let file = read_sketch_file(&a.sketch)?;
            let tree = TreeRef::of(&a.tree).await?.id(&api).await?;
            let request = sketch_request(
                tree,
                file,
                a.job.frames,
                &a.options,
                &a.job.format,
                a.job.callback_url.clone(),
            );
            start_job(&api, request, &a.job, json).await
        }
        ClientCommand::Status(a) => status(&api, &a.job, json).await,
        ClientCommand::Watch(a) => {
            let info = follow::follow(&api, &a.job).await?;
            finish(&info, json)
        }
        ClientCommand::Download(a) => {
            let info = if a.wait {
                follow::follow(&api, &a.job).await?
            } else {
                get_job(&api, &a.job).await?.0
            };
            let files = match a.t {
                Some(t) => vec![download::download_instant(&api, &info, &a.output, t).await?],
                None => download::download(&api, &info, &a.output, &a.format).await?,
            };
            let mut out = std::io::stdout().lock();
            for f in &files {
                writeln!(out, "{}", f.display()).context("writing to stdout")?;
            }
            Ok(())
        }
        ClientCommand::Cancel(a) => cancel(&api, &a.job, json).await,
        ClientCommand::Delete(a) => delete(&api, &a.job, json).await,
    }
}

/// A tree named on the command line: an existing file is uploaded, and
/// anything else is taken as a tree id (ids never contain a path
/// separator or a dot, so a name that looks like a file but does not exist
/// is reported as a missing file rather than sent as an id).
enum TreeRef {
    /// A stored tree's id.
    Id(String),
    /// A tree file read into memory, uploaded on first use.
    File { path: PathBuf, bytes: Vec<u8> },
}

impl TreeRef {
    async fn of(arg: &str) -> Result<TreeRef, Failure> {
        let path = Path::new(arg);
        let looks_like_path = arg.contains(['/', '\\', '.']);
        if !looks_like_path && !path.is_file() {
            return Ok(TreeRef::Id(arg.to_owned()));
        }
        let bytes = tokio::fs::read(path)
            .await
            .with_context(|| format!("cannot read {arg} (neither a tree id nor a readable file)"))
            .map_err(Failure::invalid_input)?;
        Ok(TreeRef::File {
            path: path.to_owned(),
            bytes,
        })
    }

    /// The tree's id, uploading the file first when it is one.
    async fn id(self, api: &Api) -> Result<String, Failure> {
        match self {
            TreeRef::Id(id) => Ok(id),
            TreeRef::File { path, bytes } => {
                let (info, _) = post_tree(api, &path, bytes, None).await?;
                eprintln!("uploaded {} as tree {}", path.display(), info.id);
                Ok(info.id)
            }
        }
    }
}

/// The media type of a tree file: from its content, else its extension.
fn media_type(path: &Path, bytes: &[u8]) -> Option<&'static str> {
    if let Some(kind) = crate::files::sniff(bytes) {
        return Some(kind.media_type());
    }
    let ext = path.extension()?.to_str()?.to_ascii_lowercase();
    match ext.as_str() {
        "glb" => Some("model/gltf-binary"),
        "gltf" => Some("model/gltf+json"),
        "json" => Some(treemorph_tree::json::MEDIA_TYPE),
        _ => None,
    }
}

async fn upload(api: &Api, a: &UploadArgs, json: bool) -> Result<(), Failure> {
    let bytes = tokio::fs::read(&a.file)
        .await
        .with_context(|| format!("cannot read {}", a.file.display()))
        .map_err(Failure::invalid_input)?;
    let (info, raw) = post_tree(api, &a.file, bytes, a.name.clone()).await?;
    print_tree(&info, &raw, json)
}

/// Uploads a tree file, named `name` or after the file's stem.
async fn post_tree(
    api: &Api,
    path: &Path,
    bytes: Vec<u8>,
    name: Option<String>,
) -> Result<(TreeInfo, serde_json::Value), Failure> {
    let media = media_type(path, &bytes).ok_or_else(|| {
        Failure::invalid_input(anyhow!(
            "{}: not a GLB, glTF or treemorph JSON tree file",
            path.display()
        ))
    })?;
    let name = name.or_else(|| {
        let stem = path.file_stem()?.to_str()?;
        (1..=256).contains(&stem.len()).then(|| stem.to_owned())
    });
    let mut url = api.v1(&["trees"])?;
    if let Some(name) = &name {
        url.query_pairs_mut().append_pair("name", name);
    }
    let request = api
        .request(Method::POST, url)
        .header(CONTENT_TYPE, media)
        .body(bytes);
    api.json::<TreeInfo>(request).await
}

async fn generate(api: &Api, a: &GenerateArgs, json: bool) -> Result<(), Failure> {
    let request = api
        .request(Method::POST, api.v1(&["trees", "generate"])?)
        .json(&GenerateRequest {
            preset: a.preset.clone(),
            seed: a.seed,
            size: a.size,
        });
    let (info, raw) = api.json::<TreeInfo>(request).await?;
    print_tree(&info, &raw, json)
}

/// Prints a stored tree: its id on stdout, a summary on stderr.
fn print_tree(info: &TreeInfo, raw: &serde_json::Value, json: bool) -> Result<(), Failure> {
    if json {
        return print_json(raw);
    }
    println_out(&info.id)?;
    let s = &info.stats;
    eprintln!(
        "tree {} \"{}\" ({}): {} branches, {} chains in {} chain groups \
         ({} alternate, {} opposite, {} whorled), {} leaves, {:.2} m tall",
        info.id,
        info.name,
        info.format,
        s.branches,
        s.chains,
        s.chain_groups,
        s.patterns.alternate,
        s.patterns.opposite,
        s.patterns.whorled,
        s.leaves,
        s.height
    );
    Ok(())
}

/// Posts a job, prints its id, and with `--wait`/`-o` follows it to its
/// end and downloads its outputs.
async fn start_job(
    api: &Api,
    request: JobRequest,
    job: &JobArgs,
    json: bool,
) -> Result<(), Failure> {
    let mut post = api.request(Method::POST, api.v1(&["jobs"])?).json(&request);
    if let Some(key) = &job.idempotency_key {
        post = post.header("Idempotency-Key", key);
    }
    let (info, raw) = api.json::<JobInfo>(post).await?;
    let wait = job.wait || job.output.is_some();
    if !wait {
        if json {
            return print_json(&raw);
        }
        println_out(&info.id)?;
        eprintln!(
            "job {} {} ({} {} frames)",
            info.id,
            info.status.as_str(),
            info.kind.as_str(),
            info.frames
        );
        return Ok(());
    }
    if !json {
        // The id first, so a script has it even while the job runs.
        println_out(&info.id)?;
    }
    let end = follow::follow(api, &info.id).await?;
    if let (Some(dir), JobStatus::Succeeded) = (&job.output, end.status) {
        let files = download::download(api, &end, dir, &[]).await?;
        eprintln!("wrote {} files to {}", files.len(), dir.display());
    }
    if json {
        print_json(&serde_json::to_value(&end).context("encoding the job document")?)?;
    }
    match end.status {
        JobStatus::Succeeded => Ok(()),
        _ => Err(follow::job_failure(&end)),
    }
}

async fn get_job(api: &Api, id: &str) -> Result<(JobInfo, serde_json::Value), Failure> {
    api.json(api.request(Method::GET, api.v1(&["jobs", id])?))
        .await
}

async fn status(api: &Api, id: &str, json: bool) -> Result<(), Failure> {
    let (info, raw) = get_job(api, id).await?;
    if json {
        return print_json(&raw);
    }
    let mut lines = vec![
        format!("job:      {}", info.id),
        format!("kind:     {}", info.kind.as_str()),
        format!("status:   {}", info.status.as_str()),
    ];
    if let Some(stage) = &info.stage {
        lines.push(format!("stage:    {stage}"));
    }
    lines.push(format!("progress: {:.0}%", info.progress * 100.0));
    lines.push(format!(
        "frames:   {}/{} ready",
        info.frames_ready, info.frames
    ));
    lines.push(format!("attempt:  {}", info.attempt));
    if info.cancel_requested {
        lines.push("cancel:   requested".to_owned());
    }
    if let Some(e) = &info.error {
        lines.push(format!("error:    {}: {}", e.code, e.message));
    }
    if let Some(result) = &info.result {
        let links = &result.links;
        let mut outputs: Vec<&str> = Vec::new();
        if links.frames.is_some() {
            outputs.push("glb");
        }
        if links.animation.is_some() {
            outputs.push("animated");
        }
        if links.stream.is_some() {
            outputs.push("delta");
        }
        outputs.push("metrics");
        lines.push(format!("outputs:  {}", outputs.join(", ")));
    }
    lines.push(format!("created:  {}", info.created_at));
    lines.push(format!("updated:  {}", info.updated_at));
    println_out(&lines.join("\n"))
}

async fn cancel(api: &Api, id: &str, json: bool) -> Result<(), Failure> {
    let (info, raw) = api
        .json::<JobInfo>(api.request(Method::POST, api.v1(&["jobs", id, "cancel"])?))
        .await?;
    if json {
        return print_json(&raw);
    }
    if info.status == JobStatus::Cancelled {
        println_out("cancelled")
    } else {
        eprintln!(
            "job {}: cancellation requested; it stops within a frame",
            info.id
        );
        println_out(&format!("{} (cancel requested)", info.status.as_str()))
    }
}

/// How long `delete` waits for a cancelled job to stop: a running job
/// stops within a frame, a job whose worker died once its lease expires.
const DELETE_PATIENCE: std::time::Duration = std::time::Duration::from_secs(120);

async fn delete(api: &Api, id: &str, json: bool) -> Result<(), Failure> {
    let started = std::time::Instant::now();
    loop {
        let response = api
            .send(api.request(Method::DELETE, api.v1(&["jobs", id])?))
            .await?;
        if response.status() == reqwest::StatusCode::NO_CONTENT {
            return if json {
                print_json(&serde_json::json!({"id": id, "deleted": true}))
            } else {
                println_out("deleted")
            };
        }
        // 200: the job was queued or running and is now cancelled or
        // stopping; it is deleted by the next request once it has ended.
        if started.elapsed() > DELETE_PATIENCE {
            return Err(failure(
                EXIT_FAILURE,
                anyhow!("job {id} was cancelled but has not stopped; try again later"),
            ));
        }
        tokio::time::sleep(std::time::Duration::from_millis(250)).await;
    }
}

/// The exit of `watch`: the final status on stdout, success only when the
/// job succeeded.
fn finish(info: &JobInfo, json: bool) -> Result<(), Failure> {
    if json {
        print_json(&serde_json::to_value(info).context("encoding the job document")?)?;
    } else {
        println_out(info.status.as_str())?;
    }
    match info.status {
        JobStatus::Succeeded => Ok(()),
        _ => Err(follow::job_failure(info)),
    }
}

fn println_out(text: &str) -> Result<(), Failure> {
    let mut out = std::io::stdout().lock();
    writeln!(out, "{text}")
        .and_then(|()| out.flush())
        .map_err(|e| failure(EXIT_FAILURE, anyhow!(e).context("writing to stdout")))
}

fn print_json(value: &serde_json::Value) -> Result<(), Failure> {
    let text = serde_json::to_string_pretty(value).context("encoding JSON")?;
    println_out(&text)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn media_types_come_from_content_then_extension() {
        let p = Path::new("x.bin");
        assert_eq!(media_type(p, b"glTF\x02\0\0\0"), Some("model/gltf-binary"));
        assert_eq!(
            media_type(p, br#"{"asset": {"version": "2.0"}}"#),
            Some("model/gltf+json")
        );
        assert_eq!(
            media_type(Path::new("t.GLB"), b"junk"),
            Some("model/gltf-binary")
        );
        assert_eq!(media_type(Path::new("t.txt"), b"junk"), None);
    }
}
