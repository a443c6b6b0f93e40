//! UniSwarm UIO1LED (being written).
