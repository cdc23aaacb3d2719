//! What the local commands (`treemorph morph|sketch`) and the client's
//! (`treemorph client morph|sketch`) share: the `--format` choice, the
//! sketch file, and the job request built from their arguments — so a job
//! means the same whether it runs here or on a server.
//!
//! Job options themselves are the wire structs
//! ([`MorphJobOptions`], [`SketchJobOptions`]) flattened into each command:
//! their fields are the flags.

use std::path::Path;

use anyhow::{Context, anyhow};
use treemorph_api::jobs::{
    JobRequest, MorphJobOptions, MorphRequest, Outputs, SketchFit, SketchInput, SketchJobOptions,
    SketchRequest, View,
};

use super::Failure;

/// Which outputs to write.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// One GLB per frame.
    Glb,
    /// One animated GLB (morph targets).
    Animated,
    /// The binary delta stream.
    Delta,
    /// All of the above.
    All,
}

/// The job outputs `--format` asks for (all when none).
pub fn outputs(formats: &[Format]) -> Outputs {
    let all = formats.is_empty() || formats.contains(&Format::All);
    Outputs {
        glb: all || formats.contains(&Format::Glb),
        animated: all || formats.contains(&Format::Animated),
        delta: all || formats.contains(&Format::Delta),
    }
}

/// A sketch file as the wire types of a sketch request.
#[derive(Debug)]
pub struct SketchFile {
    /// The camera, whole (aspect included).
    pub view: View,
    /// The polyline.
    pub sketch: SketchInput,
    /// `Some(Crown)` when the file asks for the crown fit.
    pub fit: Option<SketchFit>,
}

/// Reads a sketch file (`treemorph_sketch::parse_sketch_file`); a missing
/// or invalid file is the caller's invalid input.
pub fn read_sketch_file(path: &Path) -> Result<SketchFile, Failure> {
    let bytes = std::fs::read(path)
        .with_context(|| format!("cannot read {}", path.display()))
        .map_err(Failure::invalid_input)?;
    let file = treemorph_sketch::parse_sketch_file(&bytes)
        .map_err(|e| Failure::invalid_input(anyhow!("{}: {e}", path.display())))?;
    Ok(SketchFile {
        view: crate::pipeline::wire_view(&file.view),
        sketch: SketchInput {
            points: file.sketch.points.iter().map(|p| p.to_array()).collect(),
            closed: file.sketch.closed,
        },
        fit: match file.fit {
            treemorph_sketch::Fit::Crown => Some(SketchFit::Crown),
            treemorph_sketch::Fit::None => None,
        },
    })
}

/// A morph request from command-line arguments.
pub fn morph_request(
    (source, target): (String, String),
    frames: u32,
    options: &MorphJobOptions,
    formats: &[Format],
    callback_url: Option<String>,
) -> JobRequest {
    JobRequest::Morph(MorphRequest {
        source,
        target,
        frames,
        options: options.clone(),
        outputs: outputs(formats),
        callback_url,
    })
}

/// A sketch request from command-line arguments and a sketch file; `--fit`
/// wins over the file's `"fit"`.
pub fn sketch_request(
    tree: String,
    file: SketchFile,
    frames: u32,
    options: &SketchJobOptions,
    formats: &[Format],
    callback_url: Option<String>,
) -> JobRequest {
    JobRequest::Sketch(SketchRequest {
        tree,
        view: file.view,
        sketch: file.sketch,
        frames,
        options: SketchJobOptions {
            fit: options.fit.or(file.fit),
            ..options.clone()
        },
        outputs: outputs(formats),
        callback_url,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn formats_map_to_outputs() {
        let all = Outputs {
            glb: true,
            animated: true,
            delta: true,
        };
        assert_eq!(outputs(&[]), all);
        assert_eq!(outputs(&[Format::All]), all);
        assert_eq!(
            outputs(&[Format::Glb, Format::Delta]),
            Outputs {
                glb: true,
                animated: false,
                delta: true
            }
        );
    }

    /// The option structs flattened into a command, as the CLI uses them.
    #[derive(Debug, clap::Parser)]
    struct Flags {
        #[command(flatten)]
        morph: MorphJobOptions,
    }

    #[test]
    fn morph_flags_are_the_wire_options() {
        use clap::Parser;
        use treemorph_api::jobs::{
            AnimationEncoding, AnimationKind, LeafAssignment, Matching, ScheduleKind,
        };
        let none = Flags::try_parse_from(["t"]).unwrap();
        assert_eq!(none.morph, MorphJobOptions::default());
        let all = Flags::try_parse_from([
            "t",
            "--matching",
            "one-to-one",
            "--leaves",
            "random",
            "--no-slow-down",
            "--keyframes",
            "5",
            "--animation-encoding",
            "meshopt",
            "--animation",
            "keyframes",
            "--skeleton-joints",
            "64",
            "--schedule",
            "linear",
            "--stagger",
            "0.2",
            "--easing",
            "0.1",
            "--no-untangle",
        ])
        .unwrap();
        assert_eq!(
            all.morph,
            MorphJobOptions {
                matching: Matching::OneToOne,
                leaves: LeafAssignment::Random,
                slow_down: Some(false),
                keyframes: Some(5),
                animation_encoding: AnimationEncoding::Meshopt,
                animation: AnimationKind::Keyframes,
                skeleton_joints: Some(64),
                schedule: ScheduleKind::Linear,
                stagger: Some(0.2),
                easing: Some(0.1),
                untangle: Some(false),
            }
        );
        assert!(Flags::try_parse_from(["t", "--no-slow-down", "true"]).is_err());
    }

    #[test]
    fn a_sketch_files_aspect_reaches_the_request() {
        // Regression: the camera went domain → wire → domain through
        // `View::perspective(.., NaN)` and lost `aspect`.
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("wide.json");
        std::fs::write(
            &path,
            r#"{"view": {"eye": [0, 5, 25], "target": [0, 5, 0], "up": [0, 1, 0],
                "fov_deg": 30, "aspect": 1.7777778},
               "points": [[-0.5, -0.5], [0.5, -0.5], [0.0, 0.6]], "closed": true}"#,
        )
        .unwrap();
        let file = read_sketch_file(&path).unwrap();
        let options = SketchJobOptions {
            fit: Some(SketchFit::Crown),
            ..SketchJobOptions::default()
        };
        let request = sketch_request("t".into(), file, 4, &options, &[], None);
        let spec = crate::pipeline::JobSpec::parse(&request, &Default::default()).unwrap();
        let crate::pipeline::JobSpec::Sketch(spec) = spec else {
            panic!("not a sketch")
        };
        assert_eq!(spec.view.aspect, 1.7777778);
        assert_eq!(spec.options.fit, treemorph_sketch::Fit::Crown);
    }
}
