//! The one error type of the `human` layer. Every variant names where the problem is (stream,
//! sample index, field) so the API can answer with a precise problem+json validation entry.

/// Errors from validating, ingesting or generating human demonstrations.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum HumanError {
    #[error("stream `{stream}` is empty")]
    EmptyStream { stream: &'static str },
    #[error("stream `{stream}`: column `{field}` has {got} samples, expected {expected} (as `t`)")]
    LengthMismatch {
        stream: &'static str,
        field: String,
        expected: usize,
        got: usize,
    },
    #[error(
        "stream `{stream}` sample {index}: timestamp {t} is not strictly greater than the previous one ({previous})"
    )]
    NotIncreasing {
        stream: &'static str,
        index: usize,
        previous: f64,
        t: f64,
    },
    #[error("stream `{stream}` sample {index}: field `{field}` is not finite ({value})")]
    NonFinite {
        stream: &'static str,
        index: usize,
        field: String,
        value: f64,
    },
    #[error(
        "stream `{stream}` sample {index}: field `{field}` has {got} values, expected {expected}"
    )]
    WrongWidth {
        stream: &'static str,
        index: usize,
        field: String,
        expected: usize,
        got: usize,
    },
    #[error(
        "stream `{stream}` sample {index}: gap of {gap} s before this sample exceeds the limit of {limit} s"
    )]
    Gap {
        stream: &'static str,
        index: usize,
        gap: f64,
        limit: f64,
    },
    #[error(
        "stream `{stream}` sample {index}: angle `{field}` = {value} rad is outside ±π (±180°)"
    )]
    AngleOutOfRange {
        stream: &'static str,
        index: usize,
        field: String,
        value: f64,
    },
    #[error(
        "stream `{stream}` sample {index}: position `{field}` is {distance} m from the tracker origin (limit {limit} m)"
    )]
    PositionOutOfRange {
        stream: &'static str,
        index: usize,
        field: String,
        distance: f64,
        limit: f64,
    },
    #[error(
        "stream `{stream}` sample {index}: quaternion `{field}` has norm {norm} and cannot be normalised"
    )]
    DegenerateQuaternion {
        stream: &'static str,
        index: usize,
        field: String,
        norm: f64,
    },
    #[error(
        "the tracker ([{tracker_start}, {tracker_end}] s) and glove ([{glove_start}, {glove_end}] s, after the offset) streams do not overlap for at least two frames"
    )]
    NoOverlap {
        tracker_start: f64,
        tracker_end: f64,
        glove_start: f64,
        glove_end: f64,
    },
    #[error("`{field}` = {value} is invalid: {reason}")]
    InvalidParameter {
        field: String,
        value: f64,
        reason: &'static str,
    },
    #[error("stream `{stream}` CSV line {line}: {message}")]
    Csv {
        stream: &'static str,
        line: usize,
        message: String,
    },
    #[error("stream `{stream}` sample {index}: {reason}")]
    DegenerateHand {
        stream: &'static str,
        index: usize,
        reason: String,
    },
    #[error("stored frame array is malformed: {reason}")]
    MalformedStorage { reason: String },
    #[error(
        "synthetic trial (subject {subject}, position {position}): target is out of reach ({distance} m from the shoulder, arm length {reach} m)"
    )]
    Unreachable {
        subject: String,
        position: usize,
        distance: f64,
        reach: f64,
    },
}

impl HumanError {
    /// The stream the error is about (`tracker`, `glove`), when there is one.
    pub fn stream(&self) -> Option<&'static str> {
        match self {
            Self::EmptyStream { stream }
            | Self::LengthMismatch { stream, .. }
            | Self::NotIncreasing { stream, .. }
            | Self::NonFinite { stream, .. }
            | Self::WrongWidth { stream, .. }
            | Self::Gap { stream, .. }
            | Self::AngleOutOfRange { stream, .. }
            | Self::PositionOutOfRange { stream, .. }
            | Self::DegenerateQuaternion { stream, .. }
            | Self::DegenerateHand { stream, .. }
            | Self::Csv { stream, .. } => Some(stream),
            _ => None,
        }
    }

    /// The sample index the error is about, when there is one.
    pub fn index(&self) -> Option<usize> {
        match self {
            Self::NotIncreasing { index, .. }
            | Self::NonFinite { index, .. }
            | Self::WrongWidth { index, .. }
            | Self::Gap { index, .. }
            | Self::AngleOutOfRange { index, .. }
            | Self::PositionOutOfRange { index, .. }
            | Self::DegenerateQuaternion { index, .. }
            | Self::DegenerateHand { index, .. } => Some(*index),
            _ => None,
        }
    }

    /// The field (column) the error is about, when there is one.
    pub fn field(&self) -> Option<&str> {
        match self {
            Self::NonFinite { field, .. }
            | Self::WrongWidth { field, .. }
            | Self::AngleOutOfRange { field, .. }
            | Self::PositionOutOfRange { field, .. }
            | Self::DegenerateQuaternion { field, .. }
            | Self::LengthMismatch { field, .. }
            | Self::InvalidParameter { field, .. } => Some(field),
            Self::NotIncreasing { .. } | Self::Gap { .. } => Some("t"),
            Self::DegenerateHand { .. } => Some("points"),
            _ => None,
        }
    }

    /// A JSON-pointer-like path to the offending value, e.g. `tracker.wrist[12]`,
    /// `glove.angles[40]`, `tracker.t[3]`, `subject.hand_length_m`.
    pub fn path(&self) -> String {
        match (self.stream(), self.field(), self.index()) {
            (Some(s), Some(f), Some(i)) => format!("{s}.{}[{i}]", field_base(f)),
            (Some(s), Some(f), None) => format!("{s}.{}", field_base(f)),
            (Some(s), None, _) => s.to_string(),
            (None, Some(f), _) => f.to_string(),
            (None, None, _) => String::new(),
        }
    }
}

/// `angles[3] (index_mcp_flexion)` → `angles`: the path names the column, the message the channel.
fn field_base(field: &str) -> &str {
    field.split(['[', ' ']).next().unwrap_or(field)
}
