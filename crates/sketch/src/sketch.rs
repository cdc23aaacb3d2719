//! The artist's input: [`Sketch`] (a polyline in normalised device
//! coordinates), [`Fit`], and the sketch file format ([`SketchFile`],
//! [`parse_sketch_file`]).

use glam::Vec2;
use serde::{Deserialize, Serialize};

use crate::error::SketchError;
use crate::polygon;
use crate::view::View;

/// The crown outline the artist drew, as JSON
/// `{"points": [[x, y], …], "closed": bool}`.
///
/// Points are in normalised device coordinates of the [`View`]: x, y in
/// [-1, 1], y up (see [`View`] for the aspect ratio). A **closed** sketch is
/// a new crown silhouette (its last point joins its first; repeating the
/// first point at the end is allowed); an **open** sketch oversketches part
/// of the current silhouette between the silhouette points nearest to its
/// two ends.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Sketch {
    /// The polyline, in NDC.
    pub points: Vec<Vec2>,
    /// Whether the polyline is a closed outline.
    pub closed: bool,
}

/// How sketch coordinates relate to the crown.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Fit {
    /// Use the points as drawn (the default).
    #[default]
    None,
    /// Scale and translate the (closed) sketch so that its bounding box is
    /// the crown silhouette's screen bounding box — one sketch file then
    /// fits any tree from any distance. Non-uniform: the sketch's width and
    /// height each match the crown's.
    Crown,
}

impl Fit {
    fn is_none(&self) -> bool {
        *self == Fit::None
    }
}

impl Sketch {
    /// Most points accepted (a hand-drawn stroke is a few hundred).
    pub const MAX_POINTS: usize = 10_000;
    /// How far outside [-1, 1] a point may lie: strokes that slip off the
    /// canvas edge a little are accepted.
    pub const MARGIN: f32 = 0.1;

    /// Checks the sketch on its own (count, finiteness, range,
    /// self-intersection) and returns its distinct points (consecutive
    /// duplicates and a repeated closing point removed), closed sketches
    /// oriented counter-clockwise.
    pub fn validate(&self) -> Result<Vec<Vec2>, SketchError> {
        if self.points.len() > Sketch::MAX_POINTS {
            return Err(SketchError::TooManyPoints {
                count: self.points.len(),
                max: Sketch::MAX_POINTS,
            });
        }
        let limit = 1.0 + Sketch::MARGIN;
        for (index, p) in self.points.iter().enumerate() {
            if !p.is_finite() {
                return Err(SketchError::NonFinite {
                    what: format!("sketch point {index}"),
                });
            }
            if p.x.abs() > limit || p.y.abs() > limit {
                return Err(SketchError::PointOutOfRange {
                    index,
                    x: p.x,
                    y: p.y,
                    limit,
                });
            }
        }
        let mut points = polygon::dedup(&self.points, self.closed);
        if points.len() < 3 {
            return Err(SketchError::TooFewPoints {
                count: points.len(),
            });
        }
        if let Some((first, second)) = polygon::first_self_intersection(&points, self.closed) {
            return Err(SketchError::SelfIntersecting { first, second });
        }
        if self.closed {
            let area = polygon::signed_area(&points);
            let size = polygon::diagonal(&points);
            if area.abs() <= 1e-6 * size * size {
                return Err(SketchError::DegenerateSketch);
            }
            if area < 0.0 {
                points.reverse();
            }
        }
        Ok(points)
    }
}

/// A sketch file: the view, the sketch and how to fit it.
#[derive(Clone, Debug, PartialEq)]
pub struct SketchFile {
    /// The camera the sketch was drawn from.
    pub view: View,
    /// The sketch.
    pub sketch: Sketch,
    /// How to fit the sketch to the crown.
    pub fit: Fit,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct SketchFileJson {
    view: View,
    points: Vec<Vec2>,
    closed: bool,
    #[serde(default, skip_serializing_if = "Fit::is_none")]
    fit: Fit,
}

/// Parses a sketch file:
/// `{"view": {…}, "points": [[x, y], …], "closed": bool, "fit": "crown"}`
/// (`fit` optional: `"none"` (default) or `"crown"`; unknown fields are
/// refused). The view and the sketch are validated on their own (everything
/// that does not need the tree).
pub fn parse_sketch_file(bytes: &[u8]) -> Result<SketchFile, SketchError> {
    let json: SketchFileJson =
        serde_json::from_slice(bytes).map_err(|e| SketchError::InvalidJson(e.to_string()))?;
    let file = SketchFile {
        view: json.view,
        sketch: Sketch {
            points: json.points,
            closed: json.closed,
        },
        fit: json.fit,
    };
    file.view.camera()?;
    file.sketch.validate()?;
    if file.fit == Fit::Crown && !file.sketch.closed {
        return Err(SketchError::FitNeedsClosedSketch);
    }
    Ok(file)
}

impl SketchFile {
    /// The file as pretty JSON (what [`parse_sketch_file`] reads).
    pub fn to_json(&self) -> Vec<u8> {
        let json = SketchFileJson {
            view: self.view.clone(),
            points: self.sketch.points.clone(),
            closed: self.sketch.closed,
            fit: self.fit,
        };
        serde_json::to_vec_pretty(&json).expect("sketch files serialise")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sketch(points: &[[f32; 2]], closed: bool) -> Sketch {
        Sketch {
            points: points.iter().map(|&p| Vec2::from(p)).collect(),
            closed,
        }
    }

    #[test]
    fn validation_errors() {
        assert_eq!(
            sketch(&[[0.0, 0.0], [0.5, 0.0], [0.5, 0.0]], true).validate(),
            Err(SketchError::TooFewPoints { count: 2 })
        );
        assert_eq!(
            sketch(&[[0.0, 0.0], [0.5, f32::NAN], [0.5, 0.5]], true).validate(),
            Err(SketchError::NonFinite {
                what: "sketch point 1".into()
            })
        );
        assert_eq!(
            sketch(&[[0.0, 0.0], [1.5, 0.0], [0.5, 0.5]], true).validate(),
            Err(SketchError::PointOutOfRange {
                index: 1,
                x: 1.5,
                y: 0.0,
                limit: 1.1
            })
        );
        // Slightly off the canvas is fine.
        assert!(
            sketch(&[[0.0, 0.0], [1.05, 0.0], [0.5, 0.5]], true)
                .validate()
                .is_ok()
        );
        assert_eq!(
            sketch(&[[0.0, 0.0], [0.5, 0.5], [0.5, 0.0], [0.0, 0.5]], true).validate(),
            Err(SketchError::SelfIntersecting {
                first: 0,
                second: 2
            })
        );
        // Collinear points fold back onto themselves…
        assert!(matches!(
            sketch(&[[0.0, 0.0], [0.5, 0.0], [0.9, 0.0]], true).validate(),
            Err(SketchError::SelfIntersecting { .. })
        ));
        // …and a sliver encloses (almost) nothing.
        assert_eq!(
            sketch(&[[0.0, 0.0], [0.9, 0.0], [0.5, 1e-7]], true).validate(),
            Err(SketchError::DegenerateSketch)
        );
        let many = Sketch {
            points: vec![Vec2::ZERO; Sketch::MAX_POINTS + 1],
            closed: true,
        };
        assert_eq!(
            many.validate(),
            Err(SketchError::TooManyPoints {
                count: Sketch::MAX_POINTS + 1,
                max: Sketch::MAX_POINTS
            })
        );
    }

    #[test]
    fn closed_sketches_come_back_counter_clockwise() {
        let cw = sketch(
            &[[0.0, 0.0], [0.0, 0.5], [0.5, 0.5], [0.5, 0.0], [0.0, 0.0]],
            true,
        );
        let pts = cw.validate().unwrap();
        assert_eq!(pts.len(), 4);
        assert!(polygon::signed_area(&pts) > 0.0);
    }

    #[test]
    fn sketch_files_parse_and_round_trip() {
        let text = br#"{
            "view": {"eye": [0, 5, 25], "target": [0, 5, 0], "up": [0, 1, 0], "fov_deg": 30},
            "points": [[-0.5, -0.5], [0.5, -0.5], [0.0, 0.5]],
            "closed": true,
            "fit": "crown"
        }"#;
        let file = parse_sketch_file(text).unwrap();
        assert_eq!(file.fit, Fit::Crown);
        assert_eq!(file.sketch.points.len(), 3);
        assert_eq!(parse_sketch_file(&file.to_json()).unwrap(), file);
        let unknown =
            br#"{"view": {"eye": [0, 5, 25], "target": [0, 5, 0], "up": [0, 1, 0], "fov_deg": 30},
            "points": [[-0.5, -0.5], [0.5, -0.5], [0.0, 0.5]], "closed": true, "colour": "red"}"#;
        assert!(matches!(
            parse_sketch_file(unknown),
            Err(SketchError::InvalidJson(_))
        ));
        let open_fit =
            br#"{"view": {"eye": [0, 5, 25], "target": [0, 5, 0], "up": [0, 1, 0], "fov_deg": 30},
            "points": [[-0.5, -0.5], [0.5, -0.5], [0.0, 0.5]], "closed": false, "fit": "crown"}"#;
        assert_eq!(
            parse_sketch_file(open_fit),
            Err(SketchError::FitNeedsClosedSketch)
        );
        let bad_view =
            br#"{"view": {"eye": [0, 5, 25], "target": [0, 5, 25], "up": [0, 1, 0], "fov_deg": 30},
            "points": [[-0.5, -0.5], [0.5, -0.5], [0.0, 0.5]], "closed": true}"#;
        assert_eq!(parse_sketch_file(bad_view), Err(SketchError::EyeAtTarget));
    }
}
