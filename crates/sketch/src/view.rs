//! The camera a sketch is drawn from: [`View`] (the serde contract) and the
//! validated [`Camera`] that projects to normalised device coordinates.

use glam::{Vec2, Vec3};
use serde::{Deserialize, Serialize};

use crate::error::SketchError;

/// A camera, as JSON:
/// `{"eye": [x, y, z], "target": [x, y, z], "up": [x, y, z], "fov_deg": f}`
/// for a perspective view or
/// `{"eye": …, "target": …, "up": …, "ortho_height": h}` for an
/// orthographic one — exactly one of `fov_deg` and `ortho_height`.
/// Optional `"aspect"` (width / height of the screen, default 1).
///
/// Normalised device coordinates (NDC) put the screen in x, y ∈ [-1, 1],
/// y up, the target at the centre. `fov_deg` is the **vertical** field of
/// view in degrees, in (0, 180); `ortho_height` the height in metres that
/// the screen spans vertically. With `aspect` ≠ 1 the screen spans
/// `aspect` times as much horizontally, still mapped to x ∈ [-1, 1], so a
/// sketch drawn on a non-square canvas keeps its pixel aspect when
/// `x_ndc = 2·px/width − 1`, `y_ndc = 1 − 2·py/height`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct View {
    /// Camera position, metres.
    pub eye: Vec3,
    /// The point the camera looks at, metres.
    pub target: Vec3,
    /// Up direction (need not be orthogonal to the view direction, but not
    /// parallel to it).
    pub up: Vec3,
    /// Vertical field of view in degrees (perspective).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fov_deg: Option<f32>,
    /// Height spanned by the screen, metres (orthographic).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ortho_height: Option<f32>,
    /// Screen width / height (default 1).
    #[serde(default = "one", skip_serializing_if = "is_one")]
    pub aspect: f32,
}

fn one() -> f32 {
    1.0
}

fn is_one(v: &f32) -> bool {
    *v == 1.0
}

impl View {
    /// A perspective view.
    pub fn perspective(eye: Vec3, target: Vec3, up: Vec3, fov_deg: f32) -> View {
        View {
            eye,
            target,
            up,
            fov_deg: Some(fov_deg),
            ortho_height: None,
            aspect: 1.0,
        }
    }

    /// An orthographic view.
    pub fn orthographic(eye: Vec3, target: Vec3, up: Vec3, ortho_height: f32) -> View {
        View {
            eye,
            target,
            up,
            fov_deg: None,
            ortho_height: Some(ortho_height),
            aspect: 1.0,
        }
    }

    /// The front view the example sketches use for a tree of height `h`
    /// with its root at the origin: eye at (0, h/2, 2.5 h) looking at
    /// (0, h/2, 0), Y up, 30° vertical field of view — the whole tree fills
    /// about three quarters of the screen height.
    pub fn front(height: f32) -> View {
        let h = height.max(1e-3);
        View::perspective(
            Vec3::new(0.0, 0.5 * h, 2.5 * h),
            Vec3::new(0.0, 0.5 * h, 0.0),
            Vec3::Y,
            30.0,
        )
    }

    /// Checks the view and builds its camera; the error names the first
    /// problem.
    pub fn camera(&self) -> Result<Camera, SketchError> {
        for (what, v) in [
            ("view.eye", self.eye),
            ("view.target", self.target),
            ("view.up", self.up),
        ] {
            if !v.is_finite() {
                return Err(SketchError::NonFinite { what: what.into() });
            }
        }
        if let Some(f) = self.fov_deg
            && !f.is_finite()
        {
            return Err(SketchError::NonFinite {
                what: "view.fov_deg".into(),
            });
        }
        if let Some(h) = self.ortho_height
            && !h.is_finite()
        {
            return Err(SketchError::NonFinite {
                what: "view.ortho_height".into(),
            });
        }
        if !self.aspect.is_finite() {
            return Err(SketchError::NonFinite {
                what: "view.aspect".into(),
            });
        }
        let projection = match (self.fov_deg, self.ortho_height) {
            (Some(_), Some(_)) => return Err(SketchError::AmbiguousProjection),
            (None, None) => return Err(SketchError::MissingProjection),
            (Some(fov_deg), None) => {
                if !(fov_deg > 0.0 && fov_deg < 180.0) {
                    return Err(SketchError::FovOutOfRange { fov_deg });
                }
                Projection::Perspective {
                    tan_half: (0.5 * fov_deg.to_radians()).tan(),
                }
            }
            (None, Some(ortho_height)) => {
                if ortho_height <= 0.0 {
                    return Err(SketchError::OrthoHeightOutOfRange { ortho_height });
                }
                Projection::Orthographic {
                    half_height: 0.5 * ortho_height,
                }
            }
        };
        if self.aspect <= 0.0 {
            return Err(SketchError::AspectOutOfRange {
                aspect: self.aspect,
            });
        }
        let dir = self.target - self.eye;
        let scale = self.eye.length().max(self.target.length()).max(1.0);
        if dir.length() <= 1e-6 * scale {
            return Err(SketchError::EyeAtTarget);
        }
        let forward = dir.normalize();
        let up_len = self.up.length();
        if up_len <= 0.0 || forward.cross(self.up / up_len).length() < 1e-4 {
            return Err(SketchError::UpParallelToView);
        }
        let right = forward.cross(self.up).normalize();
        let up = right.cross(forward).normalize();
        Ok(Camera {
            eye: self.eye,
            right,
            up,
            forward,
            projection,
            aspect: self.aspect,
        })
    }
}

/// How a camera maps depth to the screen.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
enum Projection {
    Perspective { tan_half: f32 },
    Orthographic { half_height: f32 },
}

/// A validated camera: an orthonormal frame at the eye and a projection to
/// normalised device coordinates (see [`View`]).
///
/// **Depth** is the camera-space z: the distance along the view direction,
/// positive in front of the eye. The sketch deformation moves points in
/// the view plane only — at constant depth — so a displacement in NDC maps
/// to a world displacement along the camera's right and up axes
/// ([`Camera::world_delta`]), linear in the NDC displacement.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Camera {
    eye: Vec3,
    right: Vec3,
    up: Vec3,
    forward: Vec3,
    projection: Projection,
    aspect: f32,
}

impl Camera {
    /// The eye position.
    pub fn eye(&self) -> Vec3 {
        self.eye
    }

    /// Unit view direction.
    pub fn forward(&self) -> Vec3 {
        self.forward
    }

    /// Whether the camera is a perspective one.
    pub fn is_perspective(&self) -> bool {
        matches!(self.projection, Projection::Perspective { .. })
    }

    /// Camera-space depth of `p` (metres along the view direction).
    pub fn depth(&self, p: Vec3) -> f32 {
        (p - self.eye).dot(self.forward)
    }

    /// World metres per NDC unit along x and y at `depth`.
    pub fn scale_at(&self, depth: f32) -> Vec2 {
        let half_h = match self.projection {
            Projection::Perspective { tan_half } => tan_half * depth,
            Projection::Orthographic { half_height } => half_height,
        };
        Vec2::new(half_h * self.aspect, half_h)
    }

    /// Projects `p` to NDC and its depth. Points at or behind a perspective
    /// eye give non-finite coordinates; callers check depths first.
    pub fn project(&self, p: Vec3) -> (Vec2, f32) {
        let d = p - self.eye;
        let depth = d.dot(self.forward);
        let s = self.scale_at(depth);
        (
            Vec2::new(d.dot(self.right) / s.x, d.dot(self.up) / s.y),
            depth,
        )
    }

    /// The world point at NDC `ndc` and `depth`.
    pub fn unproject(&self, ndc: Vec2, depth: f32) -> Vec3 {
        self.eye + self.forward * depth + self.world_delta(ndc, depth)
    }

    /// The world displacement that moves a point at `depth` by `ndc_delta`
    /// on the screen, without changing its depth.
    pub fn world_delta(&self, ndc_delta: Vec2, depth: f32) -> Vec3 {
        let s = self.scale_at(depth);
        self.right * (ndc_delta.x * s.x) + self.up * (ndc_delta.y * s.y)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn project_unproject_round_trip() {
        for view in [
            View::front(10.0),
            View::orthographic(Vec3::new(3.0, 2.0, -9.0), Vec3::ZERO, Vec3::Y, 7.0),
        ] {
            let cam = view.camera().unwrap();
            let p = Vec3::new(1.2, 3.4, -0.7);
            let (ndc, depth) = cam.project(p);
            assert!((cam.unproject(ndc, depth) - p).length() < 1e-4);
            let moved = p + cam.world_delta(Vec2::new(0.1, -0.2), depth);
            let (ndc2, depth2) = cam.project(moved);
            assert!((depth2 - depth).abs() < 1e-4);
            assert!((ndc2 - ndc - Vec2::new(0.1, -0.2)).length() < 1e-5);
        }
        // The target projects to the centre.
        let cam = View::front(10.0).camera().unwrap();
        let (ndc, _) = cam.project(Vec3::new(0.0, 5.0, 0.0));
        assert!(ndc.length() < 1e-6);
    }

    #[test]
    fn degenerate_views_are_refused() {
        let ok = View::front(10.0);
        let mut v = ok.clone();
        v.target = v.eye;
        assert_eq!(v.camera(), Err(SketchError::EyeAtTarget));
        let mut v = ok.clone();
        v.up = Vec3::new(0.0, 0.0, -3.0);
        assert_eq!(v.camera(), Err(SketchError::UpParallelToView));
        let mut v = ok.clone();
        v.up = Vec3::ZERO;
        assert_eq!(v.camera(), Err(SketchError::UpParallelToView));
        for fov in [0.0, 180.0, -5.0, 200.0] {
            let mut v = ok.clone();
            v.fov_deg = Some(fov);
            assert_eq!(v.camera(), Err(SketchError::FovOutOfRange { fov_deg: fov }));
        }
        let mut v = ok.clone();
        v.ortho_height = Some(3.0);
        assert_eq!(v.camera(), Err(SketchError::AmbiguousProjection));
        let mut v = ok.clone();
        v.fov_deg = None;
        assert_eq!(v.camera(), Err(SketchError::MissingProjection));
        let mut v = ok.clone();
        v.fov_deg = None;
        v.ortho_height = Some(0.0);
        assert_eq!(
            v.camera(),
            Err(SketchError::OrthoHeightOutOfRange { ortho_height: 0.0 })
        );
        let mut v = ok.clone();
        v.aspect = -1.0;
        assert_eq!(
            v.camera(),
            Err(SketchError::AspectOutOfRange { aspect: -1.0 })
        );
        let mut v = ok.clone();
        v.eye.x = f32::NAN;
        assert_eq!(
            v.camera(),
            Err(SketchError::NonFinite {
                what: "view.eye".into()
            })
        );
        let mut v = ok;
        v.fov_deg = Some(f32::INFINITY);
        assert_eq!(
            v.camera(),
            Err(SketchError::NonFinite {
                what: "view.fov_deg".into()
            })
        );
    }

    #[test]
    fn json_shape() {
        let v: View = serde_json::from_str(
            r#"{"eye": [0, 5, 25], "target": [0, 5, 0], "up": [0, 1, 0], "fov_deg": 30}"#,
        )
        .unwrap();
        assert_eq!(v.fov_deg, Some(30.0));
        assert_eq!(v.aspect, 1.0);
        let back = serde_json::to_string(&v).unwrap();
        assert_eq!(
            back,
            r#"{"eye":[0.0,5.0,25.0],"target":[0.0,5.0,0.0],"up":[0.0,1.0,0.0],"fov_deg":30.0}"#
        );
        assert!(
            serde_json::from_str::<View>(
                r#"{"eye": [0, 5, 25], "target": [0, 5, 0], "up": [0, 1, 0], "fov": 30}"#
            )
            .is_err()
        );
    }
}
