//! The small f32 neural-network toolkit behind the SCL and CAE maps, written for this
//! project's sizes (a few inputs, two hidden layers of a few hundred units, batches of 256):
//!
//! * [`tanh`]: a vectorisable `tanh` used by training and serving alike.
//! * [`kernel`]: single-sample evaluation into preallocated buffers (the mapper's tick).
//! * [`mlp`]: parameters, initialisation, batched forward / backward, Adam, model tensors.
//! * [`gram_schmidt`]: guarded orthonormalisation of `H`'s columns and its gradient.
//! * [`lipschitz`]: spectral-norm projection (Gouk et al. 2021) and exact certification.
//!
//! Why not a general framework: measured before the project (shared reference), candle took
//! 3x PyTorch's time to train this model and 19.5 µs with 231 allocations per decode. The
//! loops here train in 0.3-0.9x PyTorch's time on this project's machine and decode in
//! 3.5 µs p50 without allocating (measured by `bench/`; figures in docs/learning.md).

pub mod gram_schmidt;
pub mod kernel;
pub mod lipschitz;
pub mod mlp;
pub mod tanh;

pub use kernel::Kernel;
pub use mlp::{Adam, BatchCache, Dense, Mlp};
