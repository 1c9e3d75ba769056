use thiserror::Error;

/// Errors of the motion layer; variants carry the offending numbers so the API can name the
/// field, demonstration, sample or joint.
#[non_exhaustive]
#[derive(Debug, Error, Clone, PartialEq)]
pub enum MotionError {
    #[error("too few demonstrations: {got} given, at least {needed} needed")]
    TooFewDemonstrations { got: usize, needed: usize },
    #[error("too few samples for {components} components: {got} frames, at least {needed} needed")]
    TooFewSamples {
        components: usize,
        got: usize,
        needed: usize,
    },
    #[error("demonstration {demo}: {got} position values is not {frames} frames x {joints} joints")]
    ShapeMismatch {
        demo: usize,
        frames: usize,
        joints: usize,
        got: usize,
    },
    #[error("demonstration {demo}: fewer than 3 frames ({frames})")]
    DemonstrationTooShort { demo: usize, frames: usize },
    #[error("demonstration {demo}, sample {sample}: non-finite value at joint {joint}")]
    NonFiniteSample {
        demo: usize,
        sample: usize,
        joint: usize,
    },
    #[error("demonstration {demo}, sample {sample}: time {time} does not increase")]
    NonIncreasingTime {
        demo: usize,
        sample: usize,
        time: f64,
    },
    #[error("{field}: expected {expected} joints, got {got}")]
    JointCount {
        field: &'static str,
        expected: usize,
        got: usize,
    },
    #[error("{field}: joint {joint} is not finite ({value})")]
    NonFinite {
        field: &'static str,
        joint: usize,
        value: f64,
    },
    #[error("{field}: joint {joint} = {value} outside limits [{lower}, {upper}]")]
    OutOfLimits {
        field: &'static str,
        joint: usize,
        value: f64,
        lower: f64,
        upper: f64,
    },
    #[error("invalid limits for joint {joint}: {reason}")]
    InvalidLimits { joint: usize, reason: &'static str },
    #[error("joint group {group}: {reason}")]
    InvalidGroup { group: usize, reason: &'static str },
    /// An option out of its range: `field` is the option's name (as in [`super::TrainOptions`]
    /// or [`super::TrajectoryOptions`]; the service's requests use the same names), `reason`
    /// says what is allowed.
    #[error("option {field} = {value}: {reason}")]
    InvalidOption {
        field: &'static str,
        value: f64,
        reason: std::borrow::Cow<'static, str>,
    },
    #[error("{needed} components needed for the variance threshold, at most {max} supported")]
    TooManyComponents { needed: usize, max: usize },
    #[error(
        "spline with {coefficients} coefficients exceeds the maximum {max}; use fewer intervals"
    )]
    SplineTooLarge {
        /// Knot intervals per axis and axes (PCA components) that need `coefficients`.
        intervals: usize,
        components: usize,
        coefficients: usize,
        max: usize,
    },
    #[error("group {group}: goal is {distance} from the goal-region centre, radius {radius}")]
    GoalOutsideRegion {
        group: usize,
        distance: f64,
        radius: f64,
    },
    #[error("group {group}: start is {distance} from the workspace centre, radius {radius}")]
    StartOutsideWorkspace {
        group: usize,
        distance: f64,
        radius: f64,
    },
    #[error("group {group}: no certifiable k (workspace bound {bound} needs 2k > bound, k = {k})")]
    CertificateUnattainable { group: usize, k: f64, bound: f64 },
    #[error("group {group}: the spline fit is singular")]
    SingularFit { group: usize },
    #[error("held-out index {index} out of range ({demos} demonstrations)")]
    HeldOutIndex { index: usize, demos: usize },
}
