//! Camera rigs: the Wonder3D 6-view rig and the SyncDreamer 16-view evaluation rig.
//!
//! Every crate takes its cameras from here (`docs/architecture.md`, "Conventions"). Rigs are independent of
//! image resolution; a [`crate::ViewSet`] pairs a rig with its images.

#[cfg(feature = "io")]
use std::io::Write as _;
#[cfg(feature = "io")]
use std::path::Path;

use glam::Vec3;

use crate::camera::{Camera, Projection};
use crate::error::{Error, Result};

/// Names of the Wonder3D views, in rig order.
pub const WONDER3D_VIEW_NAMES: [&str; 6] = ["front", "front_right", "right", "back", "left", "front_left"];

/// Azimuths of the Wonder3D views in degrees, in rig order (same order as
/// [`WONDER3D_VIEW_NAMES`]).
pub const WONDER3D_AZIMUTHS_DEG: [f32; 6] = [0.0, 45.0, 90.0, 180.0, -90.0, -45.0];

/// Half-extent of the Wonder3D image at the origin, world units: images span
/// `[-0.75, 0.75]²`.
pub const WONDER3D_HALF_EXTENT: f32 = 0.75;

/// Camera distance of the Wonder3D perspective rig: `0.75 / tan(fov/2)` with the fov of a
/// 35 mm lens on a 32 mm sensor, so the image spans the same 1.5 units at the origin.
/// The orthographic rig uses the same distance (it only affects depth values).
pub const WONDER3D_DISTANCE: f32 = WONDER3D_HALF_EXTENT * 35.0 / 16.0;

/// Allowed distance from a rig camera to its target, world units. Every rig frames the
/// canonical object (centred at the origin, longest side 1: the unit cube `[-0.5, 0.5]³`,
/// half-diagonal 0.87) from outside; the Wonder3D rigs sit at 1.64, SyncDreamer's at 1.5.
pub const RIG_DISTANCE_RANGE: (f32, f32) = (0.9, 100.0);

/// Allowed half-height of a rig camera's image at its target, world units (orthographic:
/// `half_height`; perspective: `distance · tan(fov_y / 2)`). The Wonder3D rigs use 0.75: the
/// unit cube fills most of the frame. Below 0.25 the object overflows every view by more
/// than twice; above 4 it covers less than an eighth of the frame, and reconstruction would
/// build a mesh for a scene many units wide at the unit-cube density (`half_height` 100 ran
/// for minutes and took gigabytes before this check).
pub const RIG_HALF_EXTENT_RANGE: (f32, f32) = (0.25, 4.0);

/// Largest allowed distance of a rig camera's target from the origin, world units: rig
/// cameras look at the canonical object.
pub const RIG_MAX_TARGET_OFFSET: f32 = 1.0;

/// One named camera of a rig.
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct RigView {
    /// View name, e.g. `front_right`; also used in file names.
    pub name: String,
    /// The camera.
    pub camera: Camera,
}

/// An ordered set of named cameras around the object.
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct ViewRig {
    /// Rig name, e.g. `wonder3d_ortho`.
    pub name: String,
    /// The views, in rig order.
    pub views: Vec<RigView>,
}

/// Position on a sphere of radius `distance` at `azimuth` / `elevation` (radians) in the
/// canonical frame: azimuth 0 is +z (the front), positive azimuth turns towards +x.
pub fn orbit_position(azimuth: f32, elevation: f32, distance: f32) -> Vec3 {
    distance * Vec3::new(elevation.cos() * azimuth.sin(), elevation.sin(), elevation.cos() * azimuth.cos())
}

impl ViewRig {
    fn orbit(
        name: &str,
        names: &[String],
        azimuths_deg: &[f32],
        elevation_deg: f32,
        distance: f32,
        projection: Projection,
    ) -> Self {
        let views = names
            .iter()
            .zip(azimuths_deg)
            .map(|(view_name, &a)| RigView {
                name: view_name.clone(),
                camera: Camera {
                    eye: orbit_position(a.to_radians(), elevation_deg.to_radians(), distance),
                    target: Vec3::ZERO,
                    up: Vec3::Y,
                    projection,
                },
            })
            .collect();
        ViewRig { name: name.to_string(), views }
    }

    fn wonder3d(name: &str, projection: Projection) -> Self {
        let names: Vec<String> = WONDER3D_VIEW_NAMES.iter().map(|s| s.to_string()).collect();
        Self::orbit(name, &names, &WONDER3D_AZIMUTHS_DEG, 0.0, WONDER3D_DISTANCE, projection)
    }

    /// The Wonder3D 6-view rig with orthographic cameras spanning `[-0.75, 0.75]²`.
    pub fn wonder3d_ortho() -> Self {
        Self::wonder3d("wonder3d_ortho", Projection::Orthographic { half_height: WONDER3D_HALF_EXTENT })
    }

    /// The Wonder3D 6-view rig with 35 mm perspective cameras (fov 49.13°) at
    /// [`WONDER3D_DISTANCE`].
    pub fn wonder3d_persp() -> Self {
        Self::wonder3d("wonder3d_persp", Projection::from_lens(35.0, 32.0))
    }

    /// The SyncDreamer 16-view evaluation rig in the y-up frame: elevation 30°, azimuth
    /// 0, 22.5, …, 337.5°, distance 1.5, the fov of fx = 280 px at 256² (49.13°).
    pub fn syncdreamer16() -> Self {
        let azimuths: Vec<f32> = (0..16).map(|i| i as f32 * 22.5).collect();
        let names: Vec<String> = (0..16).map(|i| format!("view_{i:02}")).collect();
        let fov_y = 2.0 * (128.0f32 / 280.0).atan();
        Self::orbit("syncdreamer16", &names, &azimuths, 30.0, 1.5, Projection::Perspective { fov_y })
    }

    /// A rig by its command-line name: `wonder3d-ortho`, `wonder3d-persp` or
    /// `syncdreamer16` (underscores accepted too).
    pub fn by_name(name: &str) -> Result<Self> {
        match name.replace('_', "-").as_str() {
            "wonder3d-ortho" => Ok(Self::wonder3d_ortho()),
            "wonder3d-persp" => Ok(Self::wonder3d_persp()),
            "syncdreamer16" => Ok(Self::syncdreamer16()),
            _ => Err(Error::invalid(
                "rig",
                format!("one of wonder3d-ortho, wonder3d-persp, syncdreamer16; got {name:?}"),
            )),
        }
    }

    /// Number of views.
    pub fn len(&self) -> usize {
        self.views.len()
    }

    /// True if the rig has no views.
    pub fn is_empty(&self) -> bool {
        self.views.is_empty()
    }

    /// Iterator over the cameras in rig order.
    pub fn cameras(&self) -> impl Iterator<Item = &Camera> {
        self.views.iter().map(|v| &v.camera)
    }

    /// Checks that the rig has views, unique names and valid cameras that frame the
    /// canonical unit-cube object: each camera at a distance in [`RIG_DISTANCE_RANGE`] from
    /// a target within [`RIG_MAX_TARGET_OFFSET`] of the origin, seeing a half-height in
    /// [`RIG_HALF_EXTENT_RANGE`] there. Errors name the view and the value.
    pub fn validate(&self) -> Result<()> {
        if self.views.is_empty() {
            return Err(Error::invalid("views", "at least one view"));
        }
        for (i, v) in self.views.iter().enumerate() {
            if v.name.is_empty() || v.name.contains(['/', '\\']) {
                return Err(Error::invalid(format!("views[{i}].name"), "a non-empty name without path separators"));
            }
            if self.views[..i].iter().any(|o| o.name == v.name) {
                return Err(Error::invalid(
                    format!("views[{i}].name"),
                    format!("a unique name, {:?} is repeated", v.name),
                ));
            }
            v.camera.validate().map_err(|e| match e {
                Error::Invalid { field, expected } => Error::invalid(format!("views[{i}].{field}"), expected),
                other => other,
            })?;
            check_framing(i, &v.camera)?;
        }
        Ok(())
    }
}

/// The framing part of [`ViewRig::validate`] for view `i` (the camera is already valid).
fn check_framing(i: usize, camera: &Camera) -> Result<()> {
    let distance = (camera.eye - camera.target).length();
    let (lo, hi) = RIG_DISTANCE_RANGE;
    if !(lo..=hi).contains(&distance) {
        return Err(Error::invalid(
            format!("views[{i}].camera.eye"),
            format!(
                "a camera {lo} to {hi} units from its target (outside the unit-cube object, in the canonical \
                 framing), got {distance}"
            ),
        ));
    }
    let offset = camera.target.length();
    if offset > RIG_MAX_TARGET_OFFSET {
        return Err(Error::invalid(
            format!("views[{i}].camera.target"),
            format!(
                "a target within {RIG_MAX_TARGET_OFFSET} of the origin (rigs look at the unit-cube object), got \
                 {:?} ({offset} away)",
                camera.target.to_array()
            ),
        ));
    }
    let (lo, hi) = RIG_HALF_EXTENT_RANGE;
    match camera.projection {
        Projection::Orthographic { half_height } if !(lo..=hi).contains(&half_height) => Err(Error::invalid(
            format!("views[{i}].camera.projection.half_height"),
            format!(
                "a half-height of {lo} to {hi} units (the unit-cube object in frame; the Wonder3D rig uses \
                 {WONDER3D_HALF_EXTENT}), got {half_height}"
            ),
        )),
        Projection::Perspective { fov_y } => {
            let half = distance * (0.5 * fov_y).tan();
            if (lo..=hi).contains(&half) {
                Ok(())
            } else {
                Err(Error::invalid(
                    format!("views[{i}].camera.projection.fov_y"),
                    format!(
                        "a field of view that sees {lo} to {hi} units above and below the target (the unit-cube \
                         object in frame), got {fov_y} rad at distance {distance}: {half} units"
                    ),
                ))
            }
        }
        _ => Ok(()),
    }
}

/// Rig files (feature `io`).
#[cfg(feature = "io")]
impl ViewRig {
    /// Writes the rig as JSON (`cameras.json`), atomically.
    pub fn save_json(&self, path: impl AsRef<Path>) -> Result<()> {
        let path = path.as_ref();
        let text = serde_json::to_string_pretty(self).expect("a rig always serialises");
        crate::files::write_atomic(path, |w| w.write_all(text.as_bytes()).map_err(|e| Error::io(path, e)))
    }

    /// Reads and validates a rig written by [`ViewRig::save_json`].
    pub fn load_json(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let bytes = crate::files::read_input(path)?;
        let text = String::from_utf8(bytes)
            .map_err(|e| Error::format(path, format!("byte {}", e.utf8_error().valid_up_to()), "UTF-8 JSON text"))?;
        // The key path of a value of the wrong type or range (`views[0].camera.eye`) says
        // what to fix; the line and column find it in the file.
        let mut json = serde_json::Deserializer::from_str(&text);
        let rig: ViewRig = serde_path_to_error::deserialize(&mut json).map_err(|e| {
            let key = e.path().to_string();
            let inner = e.inner();
            let at = format!("line {} column {}", inner.line(), inner.column());
            let field = if key == "." { at } else { format!("{key} ({at})") };
            Error::format(path, field, format!("a camera rig ({inner})"))
        })?;
        rig.validate().map_err(|e| e.in_file(path))?;
        Ok(rig)
    }
}
