//! The HTTP side: the I/O thread (`conn.rs`) owns every socket and hands complete request heads to a fixed
//! pool of workers, which answer them through the routes here. Workers never touch a socket or the engine:
//! renders go through the [`RenderQueue`] to the render threads.

use std::net::{IpAddr, TcpListener};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::mpsc::{channel, Receiver, RecvTimeoutError};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use raypatch::Image;

use crate::catalog::{ModelEntry, SceneEntry, ViewOutput};
use crate::conn::{Io, Limits, Mailbox, Work};
use crate::http::{parse_head, HttpError, Request, Response};
use crate::query::{parse_input, parse_render};
use crate::queue::{Frame, RateLimiter, RenderQueue};

/// Requests answered at once (each a complete head: slow clients wait on the I/O thread, not here).
pub const WORKERS: usize = 32;
/// Renders a second from one page (its client id): above any screen's refresh rate.
pub const CLIENT_FRAMES_PER_SECOND: u32 = 60;
/// Renders a second from one address, all its pages and scripts together.
pub const ADDRESS_FRAMES_PER_SECOND: u32 = 300;
/// Clients (or addresses) with renders in their recent past that the rate limits keep track of.
const MAX_TRACKED: usize = 4096;
/// How long a request waits for its render before it is answered 503.
const RENDER_WAIT: Duration = Duration::from_secs(60);

const INDEX_HTML: &str = include_str!("page/index.html");
const VIEWER_JS: &str = include_str!("page/viewer.js");
const VIEWER_CSS: &str = include_str!("page/viewer.css");

/// What the workers share: the catalog, the render queue and the rate limits.
pub struct Shared {
    pub models: Vec<ModelEntry>,
    pub scenes: Vec<SceneEntry>,
    pub info_json: String,
    pub queue: RenderQueue,
    clients: RateLimiter,
    addresses: RateLimiter,
}

impl Shared {
    pub fn new(models: Vec<ModelEntry>, scenes: Vec<SceneEntry>, info_json: String) -> Shared {
        Shared {
            models,
            scenes,
            info_json,
            queue: RenderQueue::default(),
            clients: RateLimiter::new(CLIENT_FRAMES_PER_SECOND, MAX_TRACKED, "client"),
            addresses: RateLimiter::new(ADDRESS_FRAMES_PER_SECOND, MAX_TRACKED, "address"),
        }
    }
}

/// The running HTTP side; [`Http::stop`] ends it.
pub struct Http {
    mailbox: Arc<Mailbox>,
    io: JoinHandle<()>,
}

impl Http {
    /// Starts serving `listener`: the I/O thread and [`WORKERS`] workers.
    pub fn start(listener: TcpListener, shared: Arc<Shared>, limits: Limits) -> std::io::Result<Http> {
        let (hand_off, heads) = channel::<Work>();
        let io = Io::new(listener, hand_off, limits)?;
        let mailbox = io.mailbox();
        let heads = Arc::new(Mutex::new(heads));
        for i in 0..WORKERS {
            let (heads, shared, mailbox) = (heads.clone(), shared.clone(), mailbox.clone());
            std::thread::Builder::new()
                .name(format!("viewer-http-{i}"))
                .spawn(move || work(&heads, &shared, &mailbox))?;
        }
        let io = std::thread::Builder::new().name("viewer-io".into()).spawn(move || io.run())?;
        Ok(Http { mailbox, io })
    }

    /// Stops accepting, then gives requests being answered up to `grace` to finish.
    pub fn stop(self, grace: Duration) {
        self.mailbox.stop(grace);
        let _ = self.io.join();
    }
}

/// A worker: answers complete request heads until the I/O thread is gone.
fn work(heads: &Mutex<Receiver<Work>>, shared: &Shared, mailbox: &Mailbox) {
    loop {
        let next = heads.lock().unwrap_or_else(|p| p.into_inner()).recv();
        let Ok(work) = next else { return };
        let response = match catch_unwind(AssertUnwindSafe(|| answer(&work.head, shared, work.peer))) {
            Ok(response) => response,
            Err(_) => HttpError::new(500, "server: the request handler failed").response(),
        };
        mailbox.answer(work.id, response.into_bytes());
    }
}

fn answer(head: &[u8], shared: &Shared, peer: IpAddr) -> Response {
    let result = parse_head(head).and_then(|request| route(&request, shared, peer));
    result.unwrap_or_else(|e| e.response())
}

fn route(request: &Request, shared: &Shared, peer: IpAddr) -> Result<Response, HttpError> {
    match request.path.as_str() {
        "/" | "/index.html" => Ok(Response::ok("text/html; charset=utf-8", INDEX_HTML)),
        "/viewer.js" => Ok(Response::ok("text/javascript; charset=utf-8", VIEWER_JS)),
        "/viewer.css" => Ok(Response::ok("text/css; charset=utf-8", VIEWER_CSS)),
        "/api/info" => Ok(Response::ok("application/json", shared.info_json.as_bytes())),
        "/input.png" => {
            let (scene, view) = parse_input(&request.query, &shared.scenes)?;
            Ok(Response::ok("image/png", shared.scenes[scene].thumbnails[view].as_slice()))
        }
        "/render.png" => render(request, shared, peer),
        path => Err(HttpError::new(
            404,
            format!("{:?}: not found (the viewer serves /, /render.png, /input.png and /api/info)", short(path)),
        )),
    }
}

fn short(text: &str) -> String {
    text.chars().take(60).collect()
}

fn render(request: &Request, shared: &Shared, peer: IpAddr) -> Result<Response, HttpError> {
    let query = parse_render(&request.query, &shared.models, &shared.scenes)?;
    shared.addresses.take(&peer.to_string())?;
    if let Some(client) = &query.client {
        shared.clients.take(client)?;
    }
    let output = query.output;
    let frame = match shared.queue.submit(query)?.recv_timeout(RENDER_WAIT) {
        Ok(reply) => reply?,
        Err(RecvTimeoutError::Timeout) => return Err(HttpError::new(503, "render: not done in time; try again")),
        Err(RecvTimeoutError::Disconnected) => return Err(HttpError::new(503, "server: stopping")),
    };
    let png = picture(&frame, output)
        .and_then(|image| image.encode_png())
        .map_err(|e| HttpError::new(500, format!("render: cannot make the {} picture: {e}", output.name())))?;
    let mut response = Response::ok("image/png", png);
    let region = frame.rendered.region;
    response.headers.push(("X-Render-Ms", format!("{:.2}", frame.render_time.as_secs_f64() * 1e3)));
    response.headers.push(("X-Frame-Size", format!("{}x{}", region.width, region.height)));
    Ok(response)
}

/// The picture of one output of a render.
fn picture(frame: &Frame, output: ViewOutput) -> raypatch::Result<Image> {
    let rendered = &frame.rendered;
    let (width, height) = (rendered.region.width, rendered.region.height);
    let missing = || raypatch::Error::Views(format!("the render has no {}", output.name()));
    match output {
        ViewOutput::Rgb => rendered.rgb().ok_or_else(missing),
        ViewOutput::Depth => Image::from_depth(width, height, rendered.depth().ok_or_else(missing)?, None),
        ViewOutput::Masks => {
            let (weights, slots) = rendered.segmentation().ok_or_else(missing)?;
            Image::from_segmentation(width, height, weights, slots)
        }
    }
}
