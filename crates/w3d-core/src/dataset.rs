//! What the training-set folder format (`dataset.json` beside one view-set folder per sample)
//! fixes for both its writer (`wonder3d::dataset`) and its reader (the trainer's loader in
//! `w3d-diffusion`): the format's name and the backgrounds a sample may be composited on.

/// The `format` field of `dataset.json`.
pub const FORMAT: &str = "wonder3d-rs dataset";

/// The background a training loader composites a sample over (input and targets alike).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(rename_all = "snake_case"))]
pub enum Background {
    /// 1.0 in every channel (`"white"`, what inference uses).
    White,
    /// 0.0 (`"black"`).
    Black,
    /// 0.5 (`"grey"`).
    Grey,
}

impl Background {
    /// The value of every channel of this background, in the encoded (file) range `[0, 1]`.
    pub fn value(self) -> f32 {
        match self {
            Background::White => 1.0,
            Background::Black => 0.0,
            Background::Grey => 0.5,
        }
    }

    /// The background `name` spells in `dataset.json` (`"white"`, `"black"`, `"grey"` or
    /// `"gray"`), if any.
    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            "white" => Some(Background::White),
            "black" => Some(Background::Black),
            "grey" | "gray" => Some(Background::Grey),
            _ => None,
        }
    }
}
