//! Downloading a finished job's outputs into a directory.
//!
//! Layout: `DIR/frames/NNNN.glb` (one per frame, 0-based, four digits or
//! more), `DIR/animation.glb`, `DIR/stream.tmd` (the delta stream) and
//! `DIR/metrics.json` — the names the server stores them under — or, with
//! `--t T`, only `DIR/frame_at_T.glb` (`T` with four decimals, the name
//! `treemorph morph --at` writes), rendered by the server. URLs come
//! from the job document's `result.links`, never rebuilt by hand, so the
//! client follows the server's routes.
//!
//! Each file is streamed to a temporary sibling and renamed into place
//! once complete (as [`crate::files::write_atomic`] does for whole
//! buffers), so an interrupted download never leaves a truncated file
//! under its real name and large outputs never sit whole in memory.

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Context, anyhow};
use futures_util::{StreamExt, TryStreamExt};
use reqwest::Method;
use treemorph_api::jobs::{JobInfo, JobResult, JobStatus};

use super::EXIT_NOT_FOUND;
use super::api::{Api, failure};
use super::follow::job_failure;
use crate::cli::{EXIT_FAILURE, EXIT_INVALID_INPUT, Failure};

/// Frames fetched at once.
const PARALLEL_FETCHES: usize = 4;

/// What `download --format` selects.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum DownloadFormat {
    /// One GLB per frame (`frames/NNNN.glb`).
    Glb,
    /// The animated GLB (`animation.glb`).
    Animated,
    /// The delta stream (`stream.tmd`).
    Delta,
    /// The metrics document (`metrics.json`).
    Metrics,
    /// Everything the job produced.
    All,
}

/// The result of a job that succeeded; a failure naming what to do for
/// any other job.
fn succeeded(info: &JobInfo) -> Result<&JobResult, Failure> {
    match info.status {
        JobStatus::Succeeded => {}
        JobStatus::Failed | JobStatus::Cancelled => return Err(job_failure(info)),
        JobStatus::Queued | JobStatus::Running => {
            return Err(failure(
                EXIT_INVALID_INPUT,
                anyhow!(
                    "not_ready: job {} is {}; add --wait or run `treemorph client watch {}` first",
                    info.id,
                    info.status.as_str(),
                    info.id
                ),
            ));
        }
    }
    info.result.as_ref().ok_or_else(|| {
        failure(
            EXIT_FAILURE,
            anyhow!(
                "the server reported job {} succeeded without a result",
                info.id
            ),
        )
    })
}

/// Downloads the outputs `formats` selects (everything the job produced
/// when empty or `all`) into `dir`; returns the files written, in order.
///
/// A format asked for by name that the job did not produce is a
/// not-found failure; under `all` it is skipped.
pub async fn download(
    api: &Api,
    info: &JobInfo,
    dir: &Path,
    formats: &[DownloadFormat],
) -> Result<Vec<PathBuf>, Failure> {
    let result = succeeded(info)?;
    let all = formats.is_empty() || formats.contains(&DownloadFormat::All);
    let wanted = |f| all || formats.contains(&f);
    let missing = |what: &str| {
        failure(
            EXIT_NOT_FOUND,
            anyhow!(
                "not_found: job {} has no {what} (it was not among the job's outputs)",
                info.id
            ),
        )
    };
    let links = &result.links;
    let mut plan: Vec<(String, PathBuf)> = Vec::new();
    if wanted(DownloadFormat::Glb) {
        match &links.frames {
            Some(template) => plan.extend((0..result.frames).map(|n| {
                (
                    template.replace("{n}", &n.to_string()),
                    dir.join("frames").join(format!("{n:04}.glb")),
                )
            })),
            None if !all => return Err(missing("per-frame GLBs")),
            None => {}
        }
    }
    let singles = [
        (
            DownloadFormat::Animated,
            links.animation.as_ref(),
            "animation.glb",
        ),
        (DownloadFormat::Delta, links.stream.as_ref(), "stream.tmd"),
        (
            DownloadFormat::Metrics,
            Some(&links.metrics),
            "metrics.json",
        ),
    ];
    for (format, link, name) in singles {
        if !wanted(format) {
            continue;
        }
        match link {
            Some(path) => plan.push((path.clone(), dir.join(name))),
            None if !all => return Err(missing(name)),
            None => {}
        }
    }
    if plan.iter().any(|(_, p)| p.starts_with(dir.join("frames"))) {
        std::fs::create_dir_all(dir.join("frames"))
    } else {
        std::fs::create_dir_all(dir)
    }
    .with_context(|| format!("creating {}", dir.display()))
    .map_err(|e| failure(EXIT_FAILURE, e))?;
    futures_util::stream::iter(plan)
        .map(|(path, dest)| fetch(api, path, dest))
        .buffered(PARALLEL_FETCHES)
        .try_collect()
        .await
}

/// Downloads the frame at instant `t` of a succeeded job into
/// `DIR/frame_at_T.glb`; returns the file written.
pub async fn download_instant(
    api: &Api,
    info: &JobInfo,
    dir: &Path,
    t: f32,
) -> Result<PathBuf, Failure> {
    let result = succeeded(info)?;
    let template = result.links.frame_at.as_ref().ok_or_else(|| {
        failure(
            EXIT_NOT_FOUND,
            anyhow!("not_found: this server renders no frames at instants (it is older than that)"),
        )
    })?;
    std::fs::create_dir_all(dir)
        .with_context(|| format!("creating {}", dir.display()))
        .map_err(|e| failure(EXIT_FAILURE, e))?;
    let path = template.replace("{t}", &t.to_string());
    fetch(api, path, dir.join(format!("frame_at_{t:.4}.glb"))).await
}

/// Streams one server path into `dest` atomically.
async fn fetch(api: &Api, path: String, dest: PathBuf) -> Result<PathBuf, Failure> {
    let url = api.url(&path)?;
    let mut response = api.send(api.request(Method::GET, url)).await?;
    let dir = match dest.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let local = |e: std::io::Error| {
        failure(
            EXIT_FAILURE,
            anyhow!(e).context(format!("writing {}", dest.display())),
        )
    };
    let mut tmp = tempfile::NamedTempFile::new_in(dir).map_err(local)?;
    while let Some(chunk) = response.chunk().await.map_err(|e| api.transport(e))? {
        tmp.write_all(&chunk).map_err(local)?;
    }
    // Temporary files are created private (0600); outputs are ordinary
    // files other users and tools may read.
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        tmp.as_file()
            .set_permissions(std::fs::Permissions::from_mode(0o644))
            .map_err(local)?;
    }
    tmp.as_file().sync_all().map_err(local)?;
    tmp.persist(&dest).map_err(|e| local(e.error))?;
    Ok(dest)
}
