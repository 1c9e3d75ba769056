//! Dashboard: static page assets embedded in the binary.
