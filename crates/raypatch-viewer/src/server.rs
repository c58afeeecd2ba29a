//! The HTTP side: one thread accepting connections into a bounded hand-off, a fixed pool of workers each
//! answering one request per connection, and the routes. Workers never touch the engine: renders go through
//! the [`RenderQueue`] to the render thread.

use std::net::{IpAddr, SocketAddr, TcpListener, TcpStream};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, RecvTimeoutError, TrySendError};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use raypatch::Image;

use crate::catalog::{ModelEntry, SceneEntry, ViewOutput};
use crate::http::{read_request, HttpError, Request, Response};
use crate::query::{parse_input, parse_render};
use crate::queue::{Frame, RateLimiter, RenderQueue};

/// Connections answered at once; each is one request.
pub const WORKERS: usize = 32;
/// Accepted connections waiting for a worker; beyond them a connection is answered 503 at once.
pub const MAX_WAITING_CONNECTIONS: usize = 64;
/// Renders a second from one page (its client id): above any screen's refresh rate.
pub const CLIENT_FRAMES_PER_SECOND: u32 = 60;
/// Renders a second from one address, all its pages and scripts together.
pub const ADDRESS_FRAMES_PER_SECOND: u32 = 300;
/// Clients (or addresses) with renders in their recent past that the rate limits keep track of.
const MAX_TRACKED: usize = 4096;
/// How long a request waits for its render before it is answered 503.
const RENDER_WAIT: Duration = Duration::from_secs(60);
/// How long a worker may take to write a response.
const WRITE_TIMEOUT: Duration = Duration::from_secs(10);

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
    address: SocketAddr,
    stopping: Arc<AtomicBool>,
    busy: Arc<AtomicUsize>,
    acceptor: JoinHandle<()>,
}

impl Http {
    /// Starts accepting on `listener` with [`WORKERS`] workers.
    pub fn start(listener: TcpListener, shared: Arc<Shared>) -> std::io::Result<Http> {
        let address = listener.local_addr()?;
        let stopping = Arc::new(AtomicBool::new(false));
        let busy = Arc::new(AtomicUsize::new(0));
        let (hand_off, waiting) = sync_channel::<TcpStream>(MAX_WAITING_CONNECTIONS);
        let waiting = Arc::new(Mutex::new(waiting));
        for i in 0..WORKERS {
            let (waiting, shared, busy) = (waiting.clone(), shared.clone(), busy.clone());
            std::thread::Builder::new()
                .name(format!("viewer-http-{i}"))
                .spawn(move || work(&waiting, &shared, &busy))?;
        }
        let accepting = stopping.clone();
        let acceptor = std::thread::Builder::new().name("viewer-accept".into()).spawn(move || {
            for stream in listener.incoming() {
                if accepting.load(Ordering::SeqCst) {
                    break;
                }
                let Ok(stream) = stream else { continue };
                if let Err(TrySendError::Full(mut stream)) = hand_off.try_send(stream) {
                    let _ = stream.set_write_timeout(Some(Duration::from_millis(200)));
                    let busy = HttpError::new(
                        503,
                        format!("server: over {} connections; try again", WORKERS + MAX_WAITING_CONNECTIONS),
                    );
                    let _ = busy.response().write_to(&mut stream);
                }
            }
        })?;
        Ok(Http { address, stopping, busy, acceptor })
    }

    /// Stops accepting, then gives requests being answered up to `grace` to finish.
    pub fn stop(self, grace: Duration) {
        self.stopping.store(true, Ordering::SeqCst);
        // The acceptor is blocked in accept: a connection of our own wakes it.
        let _ = TcpStream::connect_timeout(&wake_address(self.address), Duration::from_secs(1));
        let _ = self.acceptor.join();
        let start = Instant::now();
        while self.busy.load(Ordering::SeqCst) > 0 && start.elapsed() < grace {
            std::thread::sleep(Duration::from_millis(10));
        }
    }
}

/// Where to connect to reach a listener on `address` (a loopback address for one on every interface).
fn wake_address(address: SocketAddr) -> SocketAddr {
    match address.ip() {
        IpAddr::V4(ip) if ip.is_unspecified() => SocketAddr::new(std::net::Ipv4Addr::LOCALHOST.into(), address.port()),
        IpAddr::V6(ip) if ip.is_unspecified() => SocketAddr::new(std::net::Ipv6Addr::LOCALHOST.into(), address.port()),
        _ => address,
    }
}

/// A worker: answers connections until the acceptor is gone.
fn work(waiting: &Mutex<Receiver<TcpStream>>, shared: &Shared, busy: &AtomicUsize) {
    loop {
        let next = waiting.lock().unwrap_or_else(|p| p.into_inner()).recv();
        let Ok(mut stream) = next else { return };
        busy.fetch_add(1, Ordering::SeqCst);
        let peer = stream.peer_addr().map(|a| a.ip()).ok();
        let response = match catch_unwind(AssertUnwindSafe(|| answer(&mut stream, shared, peer))) {
            Ok(response) => response,
            Err(_) => HttpError::new(500, "server: the request handler failed").response(),
        };
        let _ = stream.set_write_timeout(Some(WRITE_TIMEOUT));
        let _ = response.write_to(&mut stream);
        drain(&mut stream);
        busy.fetch_sub(1, Ordering::SeqCst);
    }
}

/// Reads what the client still sends (up to 64 KiB, briefly) before closing, so that closing with unread
/// bytes does not reset the connection before the client has read the response.
fn drain(stream: &mut TcpStream) {
    use std::io::Read;
    let _ = stream.set_read_timeout(Some(Duration::from_millis(50)));
    let mut sink = [0u8; 4096];
    for _ in 0..16 {
        match stream.read(&mut sink) {
            Ok(n) if n > 0 => continue,
            _ => return,
        }
    }
}

fn answer(stream: &mut TcpStream, shared: &Shared, peer: Option<IpAddr>) -> Response {
    let result = read_request(stream).and_then(|request| route(&request, shared, peer));
    result.unwrap_or_else(|e| e.response())
}

fn route(request: &Request, shared: &Shared, peer: Option<IpAddr>) -> Result<Response, HttpError> {
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

fn render(request: &Request, shared: &Shared, peer: Option<IpAddr>) -> Result<Response, HttpError> {
    let query = parse_render(&request.query, &shared.models, &shared.scenes)?;
    let address = peer.map_or_else(|| "unknown".to_string(), |ip| ip.to_string());
    shared.addresses.take(&address)?;
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
