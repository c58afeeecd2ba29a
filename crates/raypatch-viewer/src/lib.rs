//! `render-frame --serve`: a live viewer in the browser. The command line loads models and scenes (the page
//! names them only by index), encodes each scene once per model, and serves a page that flies a camera around
//! them while one engine renders: a lower resolution while the camera moves, the full size when it stops.
//!
//! Threads: the caller's thread owns the engine and renders, with one more render thread, so that one render is
//! submitted while the other is read back (`queue.rs`: the newest camera per client); one I/O thread owns every
//! connection, collecting request heads and writing responses on non-blocking sockets (`conn.rs`); a fixed pool
//! of HTTP workers (`server.rs`) answers complete heads and encodes PNGs.

// The catalog, HTTP and query modules are public for the crate's request tests.
pub mod catalog;
mod conn;
pub mod http;
pub mod query;
mod queue;
mod serve;
mod server;

pub use serve::{main, requested, Bundled};
