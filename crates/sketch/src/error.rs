//! [`SketchError`].

use thiserror::Error;

/// Which end of an open sketch.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SketchEnd {
    /// The first point.
    Start,
    /// The last point.
    End,
}

impl std::fmt::Display for SketchEnd {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            SketchEnd::Start => "first",
            SketchEnd::End => "last",
        })
    }
}

/// Why a sketch plan could not be built. Every variant but
/// [`SketchError::Internal`] is the caller's mistake and names it.
#[derive(Clone, Debug, Error, PartialEq)]
// Exhaustive on purpose: the service's error-code table
// (`treemorph_pipeline::ErrorCoded`) must name a code for every variant.
pub enum SketchError {
    /// The sketch file is not valid JSON for the sketch format.
    #[error("invalid sketch file: {0}")]
    InvalidJson(String),
    /// A sketch needs at least 3 distinct points.
    #[error("the sketch has {count} distinct points; at least 3 are needed")]
    TooFewPoints {
        /// Distinct points given (consecutive duplicates dropped).
        count: usize,
    },
    /// More points than [`crate::Sketch::MAX_POINTS`].
    #[error("the sketch has {count} points; at most {max} are accepted")]
    TooManyPoints {
        /// Points given.
        count: usize,
        /// The limit.
        max: usize,
    },
    /// A number is NaN or infinite.
    #[error("{what} is not a finite number")]
    NonFinite {
        /// Which field, e.g. `"sketch point 3"` or `"view.eye"`.
        what: String,
    },
    /// A sketch point lies too far outside normalised device coordinates.
    #[error(
        "sketch point {index} ({x}, {y}) is outside the screen: coordinates must be within ±{limit}"
    )]
    PointOutOfRange {
        /// Index of the point.
        index: usize,
        /// Its x.
        x: f32,
        /// Its y.
        y: f32,
        /// The accepted bound (1 plus a small margin).
        limit: f32,
    },
    /// The sketch crosses itself.
    #[error("the sketch crosses itself: segment {first} intersects segment {second}")]
    SelfIntersecting {
        /// The first segment (from point `first` to the next point).
        first: usize,
        /// The second segment.
        second: usize,
    },
    /// An open sketch, spliced into the crown silhouette, makes a crown
    /// outline that crosses itself.
    #[error(
        "the oversketch, joined to the rest of the crown silhouette, makes an outline that crosses itself"
    )]
    SplicedCrownSelfIntersecting,
    /// An open sketch starts and ends at the same point of the crown
    /// silhouette, so it does not say which part of the silhouette it
    /// replaces.
    #[error(
        "the open sketch starts and ends at the same point of the crown's silhouette; draw a closed sketch to replace the whole outline"
    )]
    OpenSketchEndsCoincide,
    /// A closed sketch encloses no area (all points on a line).
    #[error("the sketch encloses no area")]
    DegenerateSketch,
    /// `fit: crown` only makes sense for a closed sketch.
    #[error(
        "\"fit\": \"crown\" needs a closed sketch; an open oversketch is drawn on the crown itself"
    )]
    FitNeedsClosedSketch,
    /// The view sets both `fov_deg` and `ortho_height`.
    #[error(
        "the view sets both fov_deg (perspective) and ortho_height (orthographic); set exactly one"
    )]
    AmbiguousProjection,
    /// The view sets neither `fov_deg` nor `ortho_height`.
    #[error(
        "the view sets neither fov_deg (perspective) nor ortho_height (orthographic); set exactly one"
    )]
    MissingProjection,
    /// The eye is at the target: no view direction.
    #[error("the view's eye and target coincide, so there is no view direction")]
    EyeAtTarget,
    /// `up` is zero or parallel to the view direction.
    #[error("the view's up vector is zero or parallel to the view direction")]
    UpParallelToView,
    /// The field of view is outside (0°, 180°).
    #[error("fov_deg {fov_deg} is out of range: it must be within (0, 180) degrees")]
    FovOutOfRange {
        /// The value given.
        fov_deg: f32,
    },
    /// The orthographic height is not positive.
    #[error("ortho_height {ortho_height} is out of range: it must be > 0")]
    OrthoHeightOutOfRange {
        /// The value given.
        ortho_height: f32,
    },
    /// The aspect ratio is not positive.
    #[error("aspect {aspect} is out of range: it must be > 0")]
    AspectOutOfRange {
        /// The value given.
        aspect: f32,
    },
    /// The tree has no leaves, so it has no crown to reshape.
    #[error("the tree has no leaves, so it has no crown to sketch")]
    NoCrown,
    /// The crown's silhouette encloses no area from this view.
    #[error("the crown's silhouette encloses no area from this view")]
    DegenerateCrown,
    /// The eye is inside the crown.
    #[error("the camera is inside the crown; move the eye outside the foliage")]
    CameraInsideCrown,
    /// Part of the tree is behind (or at) the camera of a perspective view.
    #[error(
        "node {node} of the tree is behind the camera; every part of the tree must be in front of it"
    )]
    BehindCamera {
        /// The first node found behind the camera.
        node: u32,
    },
    /// A closed sketch does not overlap the crown's silhouette.
    #[error("the sketch does not overlap the crown's silhouette from this view")]
    SketchMissesCrown,
    /// An open sketch's end is too far from the crown's silhouette.
    #[error(
        "the {end} point of the open sketch is {distance} from the crown's silhouette (screen units); it must be within {limit}"
    )]
    OpenSketchTooFar {
        /// Which end.
        end: SketchEnd,
        /// Its distance to the silhouette, in NDC units.
        distance: f32,
        /// The accepted distance ([`crate::SketchOptions::open_snap_distance`]
        /// × the crown's screen diagonal).
        limit: f32,
    },
    /// The analysis was made for another tree.
    #[error("the analysis does not belong to this tree: {0}")]
    AnalysisMismatch(String),
    /// An option is out of range.
    #[error("invalid sketch option `{option}`: {reason}")]
    InvalidOption {
        /// The option's field name.
        option: &'static str,
        /// What is wrong with it.
        reason: String,
    },
    /// A bug in the sketch pipeline.
    #[error("internal sketch error: {0}")]
    Internal(String),
}
