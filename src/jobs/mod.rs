//! Job runner: blocking CPU work off the async runtime, progress, cancellation.
