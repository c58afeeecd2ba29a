//! Every connection lives on one thread (`viewer-io`), from accept to close, on non-blocking sockets. It
//! collects request heads (bounded in bytes and in time), hands only a complete head to a worker, and writes the
//! worker's response back (bounded in time). A slow, idle or non-reading client costs a buffer here, never a
//! thread, so hundreds of them do not keep anyone else's request waiting.

use std::collections::HashMap;
use std::io::{ErrorKind, Read, Write};
use std::net::{IpAddr, Shutdown};
use std::sync::mpsc::Sender;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use mio::net::{TcpListener, TcpStream};
use mio::{Events, Interest, Poll, Token, Waker};

use crate::http::{head_end, HttpError, MAX_HEAD_BYTES};

/// The most connections open at once (fewer where the process may open fewer files: [`connection_limit`]).
pub const MAX_CONNECTIONS: usize = 1024;
/// File descriptors kept for all but connections (the listener, the engine's driver, stdio).
const RESERVED_FILES: usize = 64;
/// Responses held for clients still taking them, all together; past this a response is answered 503.
pub const MAX_OUTGOING_BYTES: usize = 64 << 20;
/// After a response, what the client still sends is read and dropped for this long (or up to
/// [`DRAIN_BYTES`]) before closing: closing with unread bytes resets the connection, and the client may lose
/// the response.
const DRAIN_TIME: Duration = Duration::from_millis(500);
const DRAIN_BYTES: usize = 64 * 1024;
/// How long to wait before accepting again after accept failed for want of files or memory.
const ACCEPT_RETRY: Duration = Duration::from_millis(100);

const LISTENER: Token = Token(0);
const WAKER: Token = Token(1);
/// The first connection's id (and token): the ones before are the listener's and the waker's.
const FIRST_ID: usize = 2;

/// The bounds on connections.
#[derive(Clone, Copy)]
pub struct Limits {
    /// Connections open at once; past it the oldest one still sending its head is closed (503) for the new one.
    pub connections: usize,
    /// How long a client has, from connecting, to send its whole request head (else 400).
    pub head: Duration,
    /// How long a client has to take its whole response (else it is closed).
    pub write: Duration,
}

impl Limits {
    pub fn new() -> Limits {
        Limits { connections: connection_limit(), head: Duration::from_secs(10), write: Duration::from_secs(10) }
    }
}

/// [`MAX_CONNECTIONS`], or fewer where the process may open fewer files.
pub fn connection_limit() -> usize {
    #[cfg(unix)]
    {
        let mut files = libc::rlimit { rlim_cur: 0, rlim_max: 0 };
        // SAFETY: getrlimit only writes the struct it is given.
        if unsafe { libc::getrlimit(libc::RLIMIT_NOFILE, &mut files) } == 0 {
            let open = usize::try_from(files.rlim_cur).unwrap_or(usize::MAX);
            return MAX_CONNECTIONS.min(open.saturating_sub(RESERVED_FILES)).max(1);
        }
    }
    MAX_CONNECTIONS
}

/// A complete request head for a worker; its response goes back through [`Mailbox::answer`].
pub struct Work {
    pub id: usize,
    pub head: Vec<u8>,
    pub peer: IpAddr,
}

/// How workers and the server's stop reach the I/O thread.
pub struct Mailbox {
    answers: Mutex<Vec<(usize, Vec<u8>)>>,
    stop_by: Mutex<Option<Instant>>,
    waker: Waker,
}

fn lock<T>(mutex: &Mutex<T>) -> MutexGuard<'_, T> {
    mutex.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

impl Mailbox {
    /// The response (as sent) to the request of connection `id`.
    pub fn answer(&self, id: usize, response: Vec<u8>) {
        lock(&self.answers).push((id, response));
        let _ = self.waker.wake();
    }

    /// Stops accepting and closes connections still sending their heads; responses being made or written get
    /// until `grace` from now.
    pub fn stop(&self, grace: Duration) {
        *lock(&self.stop_by) = Some(Instant::now() + grace);
        let _ = self.waker.wake();
    }
}

enum Stage {
    /// Reading the request head, due by `deadline`.
    Head { bytes: Vec<u8>, deadline: Instant },
    /// With a worker.
    Working,
    /// Writing the response.
    Write { bytes: Vec<u8>, sent: usize, deadline: Instant },
    /// Reading and dropping what the client still sends, after the response.
    Drain { read: usize, deadline: Instant },
}

struct Conn {
    stream: TcpStream,
    peer: IpAddr,
    stage: Stage,
}

impl Conn {
    fn deadline(&self) -> Option<Instant> {
        match self.stage {
            Stage::Head { deadline, .. } | Stage::Write { deadline, .. } | Stage::Drain { deadline, .. } => {
                Some(deadline)
            }
            Stage::Working => None,
        }
    }

    fn respond(&mut self, bytes: Vec<u8>, limits: &Limits) {
        self.stage = Stage::Write { bytes, sent: 0, deadline: Instant::now() + limits.write };
    }
}

/// The I/O thread's state: the listener, the connections, and the way to the workers.
pub struct Io {
    poll: Poll,
    listener: Option<TcpListener>,
    conns: HashMap<usize, Conn>,
    next_id: usize,
    work: Sender<Work>,
    mailbox: Arc<Mailbox>,
    limits: Limits,
    accept_again: Option<Instant>,
    scratch: Vec<u8>,
}

impl Io {
    pub fn new(listener: std::net::TcpListener, work: Sender<Work>, limits: Limits) -> std::io::Result<Io> {
        listener.set_nonblocking(true)?;
        let mut listener = TcpListener::from_std(listener);
        let poll = Poll::new()?;
        poll.registry().register(&mut listener, LISTENER, Interest::READABLE)?;
        let waker = Waker::new(poll.registry(), WAKER)?;
        let mailbox = Arc::new(Mailbox { answers: Mutex::default(), stop_by: Mutex::default(), waker });
        Ok(Io {
            poll,
            listener: Some(listener),
            conns: HashMap::new(),
            next_id: FIRST_ID,
            work,
            mailbox,
            limits,
            accept_again: None,
            scratch: vec![0; 4096],
        })
    }

    pub fn mailbox(&self) -> Arc<Mailbox> {
        self.mailbox.clone()
    }

    /// Serves connections until stopped and every response made has been written (or the grace has passed).
    pub fn run(mut self) {
        let mut events = Events::with_capacity(1024);
        loop {
            let stop_by = *lock(&self.mailbox.stop_by);
            if let Some(by) = stop_by {
                self.listener = None;
                self.conns.retain(|_, c| !matches!(c.stage, Stage::Head { .. }));
                if self.conns.is_empty() || Instant::now() >= by {
                    return;
                }
            }
            let next = self.conns.values().filter_map(Conn::deadline).chain(stop_by).chain(self.accept_again).min();
            let timeout = next.map(|t| t.saturating_duration_since(Instant::now()));
            if let Err(e) = self.poll.poll(&mut events, timeout) {
                if e.kind() == ErrorKind::Interrupted {
                    continue;
                }
                eprintln!("render-frame: error: the viewer stopped serving connections: {e}");
                return;
            }
            for event in &events {
                match event.token() {
                    LISTENER => self.accept(),
                    WAKER => {}
                    Token(id) => self.advance(id),
                }
            }
            self.take_answers();
            self.expire();
            if self.accept_again.is_some_and(|t| Instant::now() >= t) {
                self.accept_again = None;
                self.accept();
            }
        }
    }

    fn accept(&mut self) {
        loop {
            let Some(listener) = &self.listener else { return };
            match listener.accept() {
                Ok((stream, address)) => self.admit(stream, address.ip()),
                Err(e) if e.kind() == ErrorKind::WouldBlock => return,
                Err(e) if matches!(e.kind(), ErrorKind::Interrupted | ErrorKind::ConnectionAborted) => {}
                // Out of files or memory: a connection still sending its head makes room, else wait a little.
                Err(_) => {
                    if !self.evict_oldest_head() {
                        self.accept_again = Some(Instant::now() + ACCEPT_RETRY);
                        return;
                    }
                }
            }
        }
    }

    fn admit(&mut self, mut stream: TcpStream, peer: IpAddr) {
        if self.conns.len() >= self.limits.connections && !self.evict_oldest_head() {
            let message = format!("server: over {} connections, all with requests; try again", self.limits.connections);
            refuse(stream, &message);
            return;
        }
        let id = self.next_id;
        self.next_id = self.next_id.checked_add(1).unwrap_or(FIRST_ID);
        if self.poll.registry().register(&mut stream, Token(id), Interest::READABLE | Interest::WRITABLE).is_err() {
            return;
        }
        let stage = Stage::Head { bytes: Vec::new(), deadline: Instant::now() + self.limits.head };
        self.conns.insert(id, Conn { stream, peer, stage });
        // What already arrived is read now rather than at the next readiness.
        self.advance(id);
    }

    /// Closes the connection that has been sending its head longest (ids grow with time), answering it 503;
    /// false when none is.
    fn evict_oldest_head(&mut self) -> bool {
        let oldest = self.conns.iter().filter(|(_, c)| matches!(c.stage, Stage::Head { .. })).map(|(id, _)| *id).min();
        let Some(conn) = oldest.and_then(|id| self.conns.remove(&id)) else { return false };
        let message = format!(
            "server: over {} connections; this one had not sent its whole request, so it made room",
            self.limits.connections
        );
        refuse(conn.stream, &message);
        true
    }

    /// Moves connection `id` on as far as its socket allows now, closing it when done or failed.
    fn advance(&mut self, id: usize) {
        let Some(conn) = self.conns.get_mut(&id) else { return };
        if !step(conn, id, &self.work, &self.limits, &mut self.scratch) {
            self.conns.remove(&id);
        }
    }

    /// Responses the workers made, set to be written.
    fn take_answers(&mut self) {
        let answers = std::mem::take(&mut *lock(&self.mailbox.answers));
        let mut outgoing: usize = self
            .conns
            .values()
            .map(|c| match &c.stage {
                Stage::Write { bytes, sent, .. } => bytes.len() - sent,
                _ => 0,
            })
            .sum();
        for (id, bytes) in answers {
            let Some(conn) = self.conns.get_mut(&id) else { continue };
            let bytes = if outgoing + bytes.len() > MAX_OUTGOING_BYTES {
                let mib = MAX_OUTGOING_BYTES >> 20;
                let busy = format!("server: over {mib} MiB of responses waiting for slow clients; try again");
                HttpError::new(503, busy).response().into_bytes()
            } else {
                bytes
            };
            outgoing += bytes.len();
            conn.respond(bytes, &self.limits);
            self.advance(id);
        }
    }

    /// A head not in by its deadline is answered 400; a response or drain past its deadline is closed.
    fn expire(&mut self) {
        let now = Instant::now();
        let due: Vec<usize> =
            self.conns.iter().filter(|(_, c)| c.deadline().is_some_and(|d| now >= d)).map(|(id, _)| *id).collect();
        for id in due {
            let Some(conn) = self.conns.get_mut(&id) else { continue };
            if let Stage::Head { .. } = conn.stage {
                let late = HttpError::bad("request: the head did not arrive in time");
                conn.respond(late.response().into_bytes(), &self.limits);
                self.advance(id);
            } else {
                self.conns.remove(&id);
            }
        }
    }
}

/// Answers `stream` 503 with what one write without waiting takes, and closes it.
fn refuse(mut stream: TcpStream, message: &str) {
    let _ = stream.write(&HttpError::new(503, message).response().into_bytes());
}

/// One connection's I/O until its socket would block; false once it is to be closed.
fn step(conn: &mut Conn, id: usize, work: &Sender<Work>, limits: &Limits, scratch: &mut [u8]) -> bool {
    loop {
        match &mut conn.stage {
            Stage::Working => return true,
            Stage::Head { bytes, .. } => {
                // Room for the longest head and its final blank line, and no more.
                let room = (MAX_HEAD_BYTES + 4 - bytes.len()).min(scratch.len());
                let n = match conn.stream.read(&mut scratch[..room]) {
                    Ok(0) => {
                        let closed = HttpError::bad("request: the connection closed before the head ended");
                        conn.respond(closed.response().into_bytes(), limits);
                        continue;
                    }
                    Ok(n) => n,
                    Err(e) => match e.kind() {
                        ErrorKind::WouldBlock => return true,
                        ErrorKind::Interrupted => continue,
                        _ => return false,
                    },
                };
                let from = bytes.len();
                bytes.extend_from_slice(&scratch[..n]);
                if let Some(end) = head_end(bytes, from) {
                    bytes.truncate(end);
                    let head = std::mem::take(bytes);
                    conn.stage = Stage::Working;
                    // No workers means the server is stopping: the connection just closes.
                    return work.send(Work { id, head, peer: conn.peer }).is_ok();
                }
                if bytes.len() == MAX_HEAD_BYTES + 4 {
                    let long = HttpError::new(431, format!("request: the head is over {MAX_HEAD_BYTES} bytes"));
                    conn.respond(long.response().into_bytes(), limits);
                }
            }
            Stage::Write { bytes, sent, .. } => match conn.stream.write(&bytes[*sent..]) {
                Ok(0) => return false,
                Ok(n) => {
                    *sent += n;
                    if *sent == bytes.len() {
                        let _ = conn.stream.shutdown(Shutdown::Write);
                        conn.stage = Stage::Drain { read: 0, deadline: Instant::now() + DRAIN_TIME };
                    }
                }
                Err(e) => match e.kind() {
                    ErrorKind::WouldBlock => return true,
                    ErrorKind::Interrupted => continue,
                    _ => return false,
                },
            },
            Stage::Drain { read, .. } => match conn.stream.read(scratch) {
                Ok(0) => return false,
                Ok(n) => {
                    *read += n;
                    if *read >= DRAIN_BYTES {
                        return false;
                    }
                }
                Err(e) => match e.kind() {
                    ErrorKind::WouldBlock => return true,
                    ErrorKind::Interrupted => continue,
                    _ => return false,
                },
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::http::{parse_head, Response};
    use std::net::{SocketAddr, TcpStream as StdStream};
    use std::sync::mpsc::channel;

    /// An I/O thread on a free port whose worker answers `GET /big/N` with N bytes, `/slow` after 300 ms,
    /// never answers `/hang`, and answers anything else `ok`.
    fn serve(connections: usize, deadlines_ms: u64) -> (SocketAddr, Arc<Mailbox>) {
        let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let address = listener.local_addr().unwrap();
        let (hand_off, heads) = channel::<Work>();
        let deadline = Duration::from_millis(deadlines_ms);
        let limits = Limits { connections, head: deadline, write: deadline };
        let io = Io::new(listener, hand_off, limits).unwrap();
        let mailbox = io.mailbox();
        let answers = mailbox.clone();
        std::thread::spawn(move || {
            let mut hanging = Vec::new();
            for work in heads {
                let path = parse_head(&work.head).unwrap().path;
                let body = match path.strip_prefix("/big/") {
                    Some(n) => vec![b'x'; n.parse().unwrap()],
                    None if path == "/hang" => {
                        hanging.push(work.id);
                        continue;
                    }
                    None if path == "/slow" => {
                        std::thread::sleep(Duration::from_millis(300));
                        b"ok".to_vec()
                    }
                    None => b"ok".to_vec(),
                };
                answers.answer(work.id, Response::ok("text/plain", body).into_bytes());
            }
        });
        std::thread::spawn(move || io.run());
        (address, mailbox)
    }

    fn connect(address: SocketAddr, sent: &str) -> StdStream {
        let mut stream = StdStream::connect(address).unwrap();
        stream.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
        stream.write_all(sent.as_bytes()).unwrap();
        stream
    }

    /// What the server sends until it closes (a reset after some bytes ends it too).
    fn reply(mut stream: StdStream) -> String {
        let mut bytes = Vec::new();
        let _ = stream.read_to_end(&mut bytes);
        String::from_utf8_lossy(&bytes).into_owned()
    }

    const GET: &str = "GET / HTTP/1.1\r\n\r\n";

    #[test]
    fn past_the_limit_the_oldest_unfinished_head_makes_room() {
        let (address, mailbox) = serve(3, 10_000);
        let idle = connect(address, "");
        let slow = connect(address, "GET /");
        let _hang = connect(address, "GET /hang HTTP/1.1\r\n\r\n");
        std::thread::sleep(Duration::from_millis(50));
        // Full: the idle connection, the oldest still sending its head, is answered 503 and closed.
        let answered = reply(connect(address, GET));
        assert!(answered.starts_with("HTTP/1.1 200") && answered.ends_with("ok"), "{answered}");
        let evicted = reply(idle);
        assert!(evicted.starts_with("HTTP/1.1 503") && evicted.contains("made room"), "{evicted}");
        // The next makes room the same way; then all three are requests with the worker, and a new
        // connection is refused.
        let _hangs: Vec<_> = (0..2).map(|_| connect(address, "GET /hang HTTP/1.1\r\n\r\n")).collect();
        assert!(reply(slow).contains("made room"));
        std::thread::sleep(Duration::from_millis(50));
        let refused = reply(connect(address, GET));
        assert!(refused.starts_with("HTTP/1.1 503") && refused.contains("all with requests"), "{refused}");
        mailbox.stop(Duration::ZERO);
    }

    #[test]
    fn a_head_not_in_by_its_deadline_is_answered_400() {
        let (address, mailbox) = serve(8, 300);
        let slow = connect(address, "GET / HT");
        let start = Instant::now();
        let late = reply(slow);
        assert!(late.starts_with("HTTP/1.1 400") && late.contains("did not arrive in time"), "{late}");
        assert!(start.elapsed() >= Duration::from_millis(250), "answered before its deadline: {late}");
        mailbox.stop(Duration::ZERO);
    }

    #[test]
    fn a_client_not_taking_its_response_is_closed_after_the_write_deadline_and_others_are_served() {
        let (address, mailbox) = serve(8, 300);
        let size = 48 << 20;
        let reader = connect(address, &format!("GET /big/{size} HTTP/1.1\r\n\r\n"));
        std::thread::sleep(Duration::from_millis(100));
        // While the first response waits to be taken: a second one past the outgoing budget is refused, and a
        // small one is answered at once.
        let second = reply(connect(address, &format!("GET /big/{size} HTTP/1.1\r\n\r\n")));
        assert!(second.starts_with("HTTP/1.1 503") && second.contains("slow clients"), "{}", &second[..80]);
        assert!(reply(connect(address, GET)).ends_with("ok"));
        std::thread::sleep(Duration::from_millis(600));
        // Past the write deadline the connection was closed: the client gets what the sockets held, not all.
        let partial = reply(reader);
        assert!(partial.starts_with("HTTP/1.1 200") && partial.len() < size, "{} bytes", partial.len());
        mailbox.stop(Duration::ZERO);
    }

    #[test]
    fn stopping_lets_a_response_being_made_finish() {
        let (address, mailbox) = serve(8, 10_000);
        let pending = connect(address, "GET /slow HTTP/1.1\r\n\r\n");
        let unfinished = connect(address, "GET /");
        std::thread::sleep(Duration::from_millis(50));
        mailbox.stop(Duration::from_secs(5));
        assert!(reply(pending).ends_with("ok"));
        // A head still arriving is closed without an answer; new connections are not accepted.
        assert_eq!(reply(unfinished), "");
        std::thread::sleep(Duration::from_millis(100));
        assert!(StdStream::connect(address).is_err());
    }
}
