//! Human to humanlike robot motion mapping (paper eq. 1-7).

pub mod goals;
