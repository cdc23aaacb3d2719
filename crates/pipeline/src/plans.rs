//! Plans kept for instants rendered on request ([`Runner::frame_at`],
//! [`Runner::stream_at`]). A timeline scrubbed in the web viewer asks for
//! many instants of one job, and planning is most of an instant's cost
//! (about 95 of 130 ms for a 5,000-branch morph), so the plan, and the
//! probes that fix the meshes' side counts and the stream's grid, are
//! kept. A run leaves its plan and probes here too: the first instant
//! asked of a job this process just ran costs a frame, not a plan. The
//! writers of instants ([`Writers`]) are kept with the plans of the
//! [`WRITERS_KEPT`] most recently used entries: they hold a frame's meshes
//! (tens of MB for a 20,000-chain morph), so older entries drop them.
//!
//! An entry matches a job by its plan's part of the spec (trees and
//! pipeline options, not frames or outputs) and either by the key of the
//! job's stored plan ([`crate::StoredPlan::key`]: the service's renders,
//! which then need no trees), or by the very input trees it was planned
//! from (pointer identity of the `Arc`s the entry holds, so a tree that
//! was reloaded never meets a plan of an older copy), or by both: a job
//! that has not run yet finds the plan a job of the same trees and options
//! left (a re-run with other frames or outputs starts its frames at once;
//! the service's tree cache hands both jobs the same `Arc`s). Beyond
//! [`CAPACITY`] entries, or [`NODE_BUDGET`] union nodes in all, the least
//! recently used are dropped; the newest is always kept. Written here: a
//! `Vec` of four entries under a mutex is all an LRU of this size needs.
//!
//! [`Runner::frame_at`]: crate::Runner::frame_at
//! [`Runner::stream_at`]: crate::Runner::stream_at

use std::sync::{Arc, Mutex, OnceLock, PoisonError};

use treemorph_gltf::frame_glb::FrameGlbWriter;
use treemorph_gltf::stream::DeltaStreamWriter;
use treemorph_morph::MorphPlan;
use treemorph_sketch::SketchPlan;
use treemorph_verify::Plausibility;

use crate::runner::Probed;
use crate::{InputTree, JobSpec};

/// Plans kept at most: a few users scrubbing a few jobs each.
pub(crate) const CAPACITY: usize = 4;

/// Union nodes kept in all, beyond the newest plan: a plan holds a few
/// hundred bytes per node (a default 5,000-branch morph has 37,000 nodes,
/// a 20,000-chain one 102,000), so this bounds the cache near 100 MB.
pub(crate) const NODE_BUDGET: usize = 500_000;

/// Entries, most recently used first, that keep their [`Writers`]: a
/// couple of users scrubbing at once.
pub(crate) const WRITERS_KEPT: usize = 2;

/// A job's plan.
// One per kept entry, inside an `Arc`: the variants' sizes never move.
#[allow(clippy::large_enum_variant)]
#[derive(serde::Serialize, serde::Deserialize)]
pub(crate) enum Planned {
    Morph(MorphPlan),
    Sketch(SketchPlan),
}

impl Planned {
    fn nodes(&self) -> usize {
        match self {
            Planned::Morph(p) => p.topology().node_count(),
            Planned::Sketch(p) => p.topology().node_count(),
        }
    }
}

/// A plan with what it was made from, its probes once sampled, and the
/// writers of its instants once used.
pub(crate) struct Prepared {
    spec: JobSpec,
    of: Owned,
    pub plan: Planned,
    pub probed: OnceLock<Probed>,
    pub writers: Writers,
    /// The plan as stored with each job ([`crate::stored::write`]), once
    /// encoded: every job of the plan stores the same bytes, and encoding
    /// them took 6.5 ms of a default job's end.
    stored: OnceLock<Vec<u8>>,
}

impl Prepared {
    /// The plan and its probes as a job stores them, encoded once per
    /// plan; `None` until the probes are sampled (a job's frames sample
    /// them first).
    pub fn stored_bytes(&self) -> Option<&[u8]> {
        let probed = self.probed.get()?;
        let bytes = self.stored.get_or_init(|| {
            let started = std::time::Instant::now();
            let bytes = crate::stored::write(&self.plan, probed);
            tracing::debug!(
                ms = started.elapsed().as_secs_f64() * 1e3,
                bytes = bytes.len(),
                "plan encoded"
            );
            bytes
        });
        Some(bytes)
    }
}

/// The writers of a plan's instants, kept between requests. Every
/// instant of a job has the same meshers, the same first frame (which
/// fixes the bark's texture coordinates) and the same one-frame stream
/// header, with the job's blended textures in it; making them was most
/// of an instant's cost (a 4,515-chain morph's `stream?t=`: 28 of 41 ms
/// for the header, 5 for the writer). A frame GLB writer renders any
/// frame after any other and keeps the looks it blended; a stream writer
/// restarts after its header ([`DeltaStreamWriter::restart`]). So the
/// bytes are those of new writers. One of each is kept: a request that
/// finds the slot empty (another is rendering with it) makes its own and
/// keeps it if the slot is free when it is done.
///
/// A job of the plan keeps its stream writer too (`job_stream`, with the
/// frame count its header announces) and its output check's context
/// (`checker`): the next job of the same plan and frame count restarts
/// the stream after the same header, and checks with buffers already
/// made, pieces already labelled and the proofs of the same first frame
/// to try first ([`Plausibility::start_sequence`]). On the default job, making the
/// stream's meshers, blended textures and header took about 16 ms of its
/// first frame, before any frame could follow (claimed → first frame
/// computed: 30-35 ms before, 10-18 ms with the kept writer). Both hold
/// a frame's meshes, so they are dropped with the instants' writers.
#[derive(Default)]
pub(crate) struct Writers {
    pub glb: Slot<FrameGlbWriter>,
    pub stream: Slot<DeltaStreamWriter>,
    pub job_stream: Slot<(u32, DeltaStreamWriter)>,
    pub checker: Slot<Plausibility>,
}

/// One kept value, lent to one user at a time.
pub(crate) struct Slot<T>(Mutex<Option<T>>);

impl<T> Default for Slot<T> {
    fn default() -> Self {
        Slot(Mutex::new(None))
    }
}

impl<T> Slot<T> {
    /// The kept value, if no one else has it.
    pub fn take(&self) -> Option<T> {
        self.lock().take()
    }

    /// Keeps `value` unless another was kept meanwhile.
    pub fn keep(&self, value: T) {
        self.lock().get_or_insert(value);
    }

    /// Whether a value is kept.
    #[cfg(test)]
    pub(crate) fn holds(&self) -> bool {
        self.lock().is_some()
    }

    /// Drops the kept value.
    fn clear(&self) {
        self.lock().take();
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Option<T>> {
        // A panic while holding the lock leaves a valid Option.
        self.0.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

/// Whether two jobs have the same plan: the same trees and pipeline
/// options, whatever their frames and outputs (the service runs a job's
/// stored part and renders instants of the whole job; probes sample fixed
/// instants).
fn same_plan(a: &JobSpec, b: &JobSpec) -> bool {
    match (a, b) {
        (JobSpec::Morph(a), JobSpec::Morph(b)) => {
            (&a.source, &a.target, &a.options) == (&b.source, &b.target, &b.options)
        }
        (JobSpec::Sketch(a), JobSpec::Sketch(b)) => {
            (&a.tree, &a.view, &a.sketch, &a.options) == (&b.tree, &b.view, &b.sketch, &b.options)
        }
        _ => false,
    }
}

/// What a plan is looked up by, besides its spec.
#[derive(Clone, Copy)]
pub(crate) enum PlanOf<'a> {
    /// The key of the job's stored plan.
    Key(&'a str),
    /// The input trees, in the order the spec names them.
    Trees(&'a [Arc<InputTree>]),
    /// A job's key and the trees its plan was made from: found by either.
    Both(&'a str, &'a [Arc<InputTree>]),
}

/// [`PlanOf`], held by an entry: the key, the trees, or both.
struct Owned {
    key: Option<String>,
    trees: Option<Vec<Arc<InputTree>>>,
}

impl Owned {
    fn matches(&self, of: PlanOf<'_>) -> bool {
        match of {
            PlanOf::Key(b) => self.key.as_deref() == Some(b),
            PlanOf::Trees(b) => self.trees.as_ref().is_some_and(|a| {
                a.len() == b.len() && a.iter().zip(b).all(|(a, b)| Arc::ptr_eq(a, b))
            }),
            PlanOf::Both(key, trees) => {
                self.matches(PlanOf::Key(key)) || self.matches(PlanOf::Trees(trees))
            }
        }
    }
}

impl From<PlanOf<'_>> for Owned {
    fn from(of: PlanOf<'_>) -> Owned {
        let (key, trees) = match of {
            PlanOf::Key(key) => (Some(key), None),
            PlanOf::Trees(trees) => (None, Some(trees)),
            PlanOf::Both(key, trees) => (Some(key), Some(trees)),
        };
        Owned {
            key: key.map(str::to_owned),
            trees: trees.map(<[_]>::to_vec),
        }
    }
}

/// The kept plans, most recently used first.
#[derive(Default)]
pub(crate) struct Plans {
    entries: Mutex<Vec<Arc<Prepared>>>,
}

impl std::fmt::Debug for Plans {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let kept = self.lock().len();
        f.debug_struct("Plans").field("kept", &kept).finish()
    }
}

impl Plans {
    fn lock(&self) -> std::sync::MutexGuard<'_, Vec<Arc<Prepared>>> {
        // A panic while holding the lock leaves a valid Vec: keep using it.
        self.entries.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Plans kept.
    #[cfg(test)]
    pub fn len(&self) -> usize {
        self.lock().len()
    }

    /// Entries that keep a writer.
    #[cfg(test)]
    pub fn with_writers(&self) -> usize {
        self.lock()
            .iter()
            .filter(|e| {
                let w = &e.writers;
                w.glb.holds() || w.stream.holds() || w.job_stream.holds() || w.checker.holds()
            })
            .count()
    }

    /// The plan of `spec` kept under `of`, if any (it becomes the most
    /// recently used).
    pub fn get(&self, spec: &JobSpec, of: PlanOf<'_>) -> Option<Arc<Prepared>> {
        let mut entries = self.lock();
        let at = entries
            .iter()
            .position(|e| same_plan(&e.spec, spec) && e.of.matches(of))?;
        let entry = entries.remove(at);
        entries.insert(0, entry.clone());
        drop_older_writers(&entries);
        Some(entry)
    }

    /// Keeps a plan (and its probes, when known) as the most recently used;
    /// returns it.
    pub fn insert(
        &self,
        spec: JobSpec,
        of: PlanOf<'_>,
        plan: Planned,
        probed: Option<Probed>,
    ) -> Arc<Prepared> {
        let entry = Arc::new(Prepared {
            spec,
            of: of.into(),
            plan,
            probed: probed.map(OnceLock::from).unwrap_or_default(),
            writers: Writers::default(),
            stored: OnceLock::new(),
        });
        let mut entries = self.lock();
        // A plan of the same job from reloaded trees replaces the older;
        // one under the same key too (planned again after its stored
        // copy could not be read). Other jobs' keys keep theirs.
        entries.retain(|e| {
            !same_plan(&e.spec, &entry.spec)
                || matches!((&e.of.key, &entry.of.key), (Some(a), Some(b)) if a != b)
        });
        entries.insert(0, entry.clone());
        let mut nodes = 0;
        let keep = entries
            .iter()
            .take(CAPACITY)
            .take_while(|e| {
                nodes += e.plan.nodes();
                nodes <= NODE_BUDGET
            })
            .count();
        entries.truncate(keep.max(1));
        drop_older_writers(&entries);
        entry
    }
}

/// Frees the writers of the entries past the [`WRITERS_KEPT`] most
/// recently used.
fn drop_older_writers(entries: &[Arc<Prepared>]) {
    for e in entries.iter().skip(WRITERS_KEPT) {
        e.writers.glb.clear();
        e.writers.stream.clear();
        e.writers.job_stream.clear();
        e.writers.checker.clear();
    }
}
