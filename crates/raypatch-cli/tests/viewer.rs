//! `render-frame --serve` as a process: hostile requests get one-line errors and the server keeps serving,
//! 20 clients at once get their frames, two rendering at once get each their own, a flood gets errors without
//! the server's memory growing, hundreds of slow clients do not keep a request waiting, Ctrl-C and SIGTERM stop
//! it cleanly (exit 130 and 143, no temporary left), and the endpoint renders exactly what `render-frame --pose`
//! renders.
#![cfg(unix)]

mod common;

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use common::{fails, golden, root};
use raypatch::Image;

const BUNDLED_MODEL: &str = "assets/models/fitted_scene-2000000_rpsrt_k4.safetensors";
const BUNDLED_SCENE: &str = "assets/scenes/scene-2000000.safetensors";

/// A running `render-frame --serve --port 0`, killed if a test fails before stopping it.
struct Viewer {
    child: Child,
    address: SocketAddr,
}

impl Viewer {
    fn start(args: &[&str]) -> Viewer {
        Viewer::start_with(args, &[])
    }

    /// `start` with environment variables set.
    fn start_with(args: &[&str], vars: &[(&str, &std::path::Path)]) -> Viewer {
        let mut child = Command::new(env!("CARGO_BIN_EXE_render-frame"))
            .args(["--serve", "--port", "0"])
            .args(args)
            .envs(vars.iter().copied())
            .current_dir(root())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let mut stdout = BufReader::new(child.stdout.take().unwrap());
        let mut line = String::new();
        stdout.read_line(&mut line).unwrap();
        let url = line.split_whitespace().find(|w| w.starts_with("http://")).unwrap_or_else(|| panic!("{line:?}"));
        let address = url.trim_start_matches("http://").trim_end_matches('/').parse().unwrap();
        // The rest of stdout ("stopped") is read by `stop`.
        child.stdout = Some(stdout.into_inner());
        Viewer { child, address }
    }

    /// Sends Ctrl-C; the exit code (130 once it stopped cleanly) and what it printed after its first line.
    fn stop(self) -> (i32, String) {
        self.stop_with(libc::SIGINT)
    }

    fn stop_with(mut self, signal: i32) -> (i32, String) {
        assert_eq!(unsafe { libc::kill(self.child.id() as libc::pid_t, signal) }, 0);
        let start = Instant::now();
        let status = loop {
            if let Some(status) = self.child.try_wait().unwrap() {
                break status;
            }
            assert!(start.elapsed() < Duration::from_secs(30), "the viewer did not stop on Ctrl-C");
            std::thread::sleep(Duration::from_millis(20));
        };
        let mut rest = String::new();
        self.child.stdout.take().unwrap().read_to_string(&mut rest).unwrap();
        (status.code().unwrap_or(-1), rest)
    }

    fn memory_bytes(&self) -> u64 {
        let status = std::fs::read_to_string(format!("/proc/{}/status", self.child.id())).unwrap();
        let line = status.lines().find(|l| l.starts_with("VmRSS:")).unwrap();
        line.split_whitespace().nth(1).unwrap().parse::<u64>().unwrap() * 1024
    }
}

impl Drop for Viewer {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// An HTTP response: status, headers (lower-case names) and body.
struct Reply {
    status: u16,
    headers: String,
    body: Vec<u8>,
}

impl Reply {
    fn text(&self) -> String {
        String::from_utf8_lossy(&self.body).into_owned()
    }

    fn image(&self) -> Image {
        assert!(self.headers.contains("content-type: image/png"), "{}", self.headers);
        Image::decode_png("response", &self.body).unwrap()
    }
}

/// Sends raw bytes as a request and reads the whole response.
fn send(address: SocketAddr, request: &[u8]) -> Reply {
    let mut stream = TcpStream::connect(address).unwrap();
    stream.set_read_timeout(Some(Duration::from_secs(120))).unwrap();
    stream.write_all(request).unwrap();
    let mut response = Vec::new();
    stream.read_to_end(&mut response).unwrap();
    let end = response.windows(4).position(|w| w == b"\r\n\r\n").expect("a response head");
    let head = String::from_utf8_lossy(&response[..end]).to_lowercase();
    let status = head.split(' ').nth(1).and_then(|s| s.parse().ok()).expect("a status");
    Reply { status, headers: head, body: response[end + 4..].to_vec() }
}

fn get(address: SocketAddr, target: &str) -> Reply {
    send(address, format!("GET {target} HTTP/1.1\r\nHost: test\r\n\r\n").as_bytes())
}

/// A pose (row-major camera-to-world, OpenGL axes) looking at the origin from `degrees` around it.
fn orbit_pose(degrees: f64) -> String {
    let camera = raypatch::Camera::msn(glam::DVec3::new(6.0, 0.0, 3.0), 80, 60).unwrap().orbited(degrees);
    let (_, opencv) = camera.as_pinhole().unwrap();
    let opengl = glam::DMat4::from_cols(opencv.x_axis, -opencv.y_axis, -opencv.z_axis, opencv.w_axis);
    opengl.transpose().to_cols_array().map(|v| v.to_string()).join(",")
}

#[test]
fn hostile_requests_get_one_line_errors_and_the_viewer_keeps_serving() {
    let viewer = Viewer::start(&[]);
    let address = viewer.address;
    // A client that connects and sends nothing must not keep others waiting.
    let _silent = TcpStream::connect(address).unwrap();
    let identity = "1,0,0,0,0,1,0,0,0,0,1,0,0,0,0,1";
    let long_header = format!("GET / HTTP/1.1\r\nX-Pad: {}\r\n\r\n", "a".repeat(9000));
    let cases: Vec<(Vec<u8>, u16, &str)> = vec![
        (b"GET /render.png?size=100000x100000 HTTP/1.1\r\n\r\n".to_vec(), 400, "size: "),
        (b"GET /render.png?size=1024x1024 HTTP/1.1\r\n\r\n".to_vec(), 400, "at most 262144 pixels"),
        (b"GET /render.png?size=81x60 HTTP/1.1\r\n\r\n".to_vec(), 400, "divisible by the model's patch size k=4"),
        (
            format!("GET /render.png?pose={} HTTP/1.1\r\n\r\n", identity.replacen('1', "NaN", 1)).into_bytes(),
            400,
            "pose: number 0",
        ),
        (b"GET /render.png?pose=1,2,3 HTTP/1.1\r\n\r\n".to_vec(), 400, "pose: 3 numbers"),
        (
            format!("GET /render.png?pose={} HTTP/1.1\r\n\r\n", identity.replacen('1', "2", 1)).into_bytes(),
            400,
            "orthonormal",
        ),
        (b"GET /render.png?model=1 HTTP/1.1\r\n\r\n".to_vec(), 400, "model: `1` is not one of the 1 models"),
        (b"GET /render.png?scene=18446744073709551616 HTTP/1.1\r\n\r\n".to_vec(), 400, "scene: "),
        (
            b"GET /render.png?scene=..%2F..%2Fetc%2Fpasswd HTTP/1.1\r\n\r\n".to_vec(),
            400,
            "scene: `../../etc/passwd` is not",
        ),
        (b"GET /render.png?model=/etc/passwd HTTP/1.1\r\n\r\n".to_vec(), 400, "model: "),
        (b"GET /render.png?path=/etc/passwd HTTP/1.1\r\n\r\n".to_vec(), 400, "parameter `path`: unknown"),
        (b"GET /render.png?output=masks HTTP/1.1\r\n\r\n".to_vec(), 400, "output: `masks`"),
        (b"GET /render.png?client=../x HTTP/1.1\r\n\r\n".to_vec(), 400, "client: "),
        (b"GET /render.png?model=0&model=0 HTTP/1.1\r\n\r\n".to_vec(), 400, "given twice"),
        (b"GET /input.png?scene=0&view=7 HTTP/1.1\r\n\r\n".to_vec(), 400, "view: "),
        (b"GET /../../etc/passwd HTTP/1.1\r\n\r\n".to_vec(), 404, "not found"),
        (b"GET /assets/models/ HTTP/1.1\r\n\r\n".to_vec(), 404, "not found"),
        (format!("GET /render.png?{} HTTP/1.1\r\n\r\n", "a".repeat(5000)).into_bytes(), 414, "request target"),
        (long_header.into_bytes(), 431, "head is over"),
        (b"POST /render.png HTTP/1.1\r\nContent-Length: 4\r\n\r\nabcd".to_vec(), 405, "only GET"),
        (b"GET / HTTP/1.1\r\nContent-Length: 4\r\n\r\nabcd".to_vec(), 413, "request body"),
        (b"\x00\xff\xfe garbage\r\n\r\n".to_vec(), 400, "request"),
        (b"GET /render.png?pose=%ZZ HTTP/1.1\r\n\r\n".to_vec(), 400, "pose: invalid percent-encoding"),
        (b"GET /\r\n\r\n".to_vec(), 400, "request line"),
    ];
    for (request, status, text) in &cases {
        let reply = send(address, request);
        let shown = String::from_utf8_lossy(&request[..request.len().min(80)]).into_owned();
        assert_eq!(reply.status, *status, "{shown}: {}", reply.text());
        assert!(reply.text().contains(text), "{shown}: {:?} lacks {text:?}", reply.text());
        assert_eq!(reply.text().lines().count(), 1, "{shown}: not one line: {:?}", reply.text());
    }
    // A connection closed before its head ended, then the viewer still serves the page, its facts and frames.
    drop(TcpStream::connect(address).unwrap().write_all(b"GET /ren"));
    let page = get(address, "/");
    assert!(page.status == 200 && page.text().contains("<script src=\"/viewer.js\">"));
    assert_eq!(get(address, "/viewer.js").status, 200);
    let info: serde_json::Value = serde_json::from_slice(&get(address, "/api/info").body).unwrap();
    assert_eq!(info["models"][0]["k"], 4);
    assert_eq!(info["models"][0]["outputs"], serde_json::json!(["rgb"]));
    // Which precision and kernels render (the viewer's --precision, f32 by default).
    assert!(info["models"][0]["computes"].as_str().unwrap().starts_with("precision f32, "), "{info}");
    // Names, never paths: nothing the page sees says where the files lie.
    assert!(!info.to_string().contains("assets/"), "{info}");
    assert_eq!(info["scenes"][0]["sizes"][0], serde_json::json!([80, 60]));
    let thumbnail = get(address, "/input.png?scene=0&view=0").image();
    assert_eq!((thumbnail.width(), thumbnail.height()), (80, 60));
    let frame = get(address, &format!("/render.png?pose={}&size=40x28", orbit_pose(30.0)));
    assert_eq!(frame.status, 200, "{}", frame.text());
    assert!(frame.headers.contains("x-render-ms: "), "{}", frame.headers);
    assert_eq!((frame.image().width(), frame.image().height()), (40, 28));
    let (code, printed) = viewer.stop();
    assert_eq!((code, printed.trim()), (130, "raypatch viewer: stopped"));
}

/// SIGINT and SIGTERM while clients ask for frames of new sizes (new render plans, pipelines compiled and the
/// pipeline cache written at the stop): the viewer finishes, exits with 128 + the signal, and leaves no
/// temporary where it writes.
#[test]
fn a_signal_while_serving_exits_128_plus_it_and_leaves_no_temporary() {
    for (signal, code) in [(libc::SIGINT, 130), (libc::SIGTERM, 143)] {
        let cache = tempfile::TempDir::new().unwrap();
        let viewer = Viewer::start_with(&[], &[("RAYPATCH_CACHE_DIR", cache.path())]);
        let address = viewer.address;
        let frame = get(address, &format!("/render.png?pose={}&size=40x28", orbit_pose(10.0)));
        assert_eq!(frame.status, 200, "{}", frame.text());
        let done = Arc::new(AtomicBool::new(false));
        let asking = done.clone();
        let client = std::thread::spawn(move || {
            for n in 1.. {
                let Ok(mut stream) = TcpStream::connect(address) else { break };
                let target = format!("/render.png?pose={}&size={}x28", orbit_pose(n as f64), 40 + 4 * (n % 8));
                let _ = stream.write_all(format!("GET {target} HTTP/1.1\r\nHost: test\r\n\r\n").as_bytes());
                let _ = stream.read_to_end(&mut Vec::new());
                if asking.load(Ordering::Relaxed) {
                    break;
                }
            }
        });
        std::thread::sleep(Duration::from_millis(500));
        let (exit, printed) = viewer.stop_with(signal);
        done.store(true, Ordering::Relaxed);
        client.join().unwrap();
        assert_eq!((exit, printed.trim()), (code, "raypatch viewer: stopped"));
        let left = common::files(cache.path());
        assert!(left.iter().all(|f| !f.ends_with(".tmp") && !f.contains(".raypatch-")), "{left:?}");
    }
}

#[test]
fn twenty_clients_get_their_frames_and_floods_get_errors_without_memory_growing() {
    let viewer = Viewer::start(&[]);
    let address = viewer.address;
    let clients: Vec<_> = (0..20)
        .map(|i| {
            std::thread::spawn(move || {
                for j in 0..2 {
                    let size = if (i + j) % 2 == 0 { "80x60" } else { "40x28" };
                    let target = format!("/render.png?pose={}&size={size}", orbit_pose(f64::from(i * 18 + j)));
                    let reply = get(address, &target);
                    assert_eq!(reply.status, 200, "client {i}: {}", reply.text());
                    let image = reply.image();
                    assert_eq!(format!("{}x{}", image.width(), image.height()), size, "client {i}");
                }
            })
        })
        .collect();
    for client in clients {
        client.join().expect("every client gets its frames");
    }
    // Floods: bad requests, and renders from one page id (each replaces the one waiting: 409; past its frame
    // rate: 429), with sizes enough to fill the render plan cache. Twice: the second must not grow memory.
    let flood = || {
        let threads: Vec<_> = (0..16)
            .map(|t| {
                std::thread::spawn(move || {
                    let mut statuses = Vec::new();
                    for i in 0..120usize {
                        let target = match i % 4 {
                            0 => format!(
                                "/render.png?size={}x4&client=flood&pose={}",
                                4 * (1 + (t * 7 + i) % 12),
                                orbit_pose(i as f64)
                            ),
                            1 => "/render.png?pose=NaN".to_string(),
                            2 => format!("/render.png?scene={i}&size=999999x999999"),
                            _ => "/render.png?model=../../etc/passwd".to_string(),
                        };
                        statuses.push(get(address, &target).status);
                    }
                    statuses
                })
            })
            .collect();
        threads.into_iter().flat_map(|t| t.join().unwrap()).collect::<Vec<u16>>()
    };
    let first = flood();
    let before = viewer.memory_bytes();
    let second = flood();
    let after = viewer.memory_bytes();
    for statuses in [&first, &second] {
        assert!(statuses.iter().all(|s| [200, 400, 409, 429, 503].contains(s)), "{statuses:?}");
        assert_eq!(statuses.iter().filter(|&&s| s == 400).count(), 16 * 90);
        assert!(statuses.contains(&429), "no rate-limited render: {statuses:?}");
    }
    // Replaced renders: the first flood's come in a burst (the page id's bucket is full). The second's come at
    // the bucket's refill, one per 1/60 s, and replace one another only when a render takes longer than that.
    assert!(first.contains(&409), "no replaced render: {first:?}");
    assert!(after < before + (48 << 20), "memory grew from {before} to {after} bytes in a second flood");
    std::thread::sleep(Duration::from_millis(1100));
    let reply = get(address, "/render.png");
    assert_eq!(reply.status, 200, "after the floods: {}", reply.text());
    assert_eq!(viewer.stop().0, 130);
}

/// Two clients whose renders run at once (on the two render threads, one submitted while the other is read
/// back) each get their own camera's frame, as rendered one request at a time.
#[test]
fn two_clients_rendering_at_once_each_get_their_own_frames() {
    let viewer = Viewer::start(&[]);
    let address = viewer.address;
    let target = |degrees: f64| format!("/render.png?pose={}", orbit_pose(degrees));
    let alone: Vec<Image> = [0.0, 90.0].map(|degrees| get(address, &target(degrees)).image()).to_vec();
    assert_ne!(alone[0], alone[1]);
    let clients: Vec<_> = [0.0, 90.0]
        .into_iter()
        .zip(alone)
        .map(|(degrees, expected)| {
            let target = target(degrees);
            std::thread::spawn(move || {
                for _ in 0..12 {
                    let reply = get(address, &target);
                    assert_eq!(reply.status, 200, "{degrees}°: {}", reply.text());
                    assert!(reply.image() == expected, "{degrees}°: not the frame rendered alone");
                }
            })
        })
        .collect();
    for client in clients {
        client.join().expect("both clients get their frames");
    }
    assert_eq!(viewer.stop().0, 130);
}

/// The soft limit on open files, raised towards `wanted` as far as the hard limit allows (a viewer started
/// after inherits it).
fn open_files_for(wanted: u64) -> u64 {
    let mut limit = libc::rlimit { rlim_cur: 0, rlim_max: 0 };
    assert_eq!(unsafe { libc::getrlimit(libc::RLIMIT_NOFILE, &mut limit) }, 0);
    if limit.rlim_cur < wanted {
        limit.rlim_cur = wanted.min(limit.rlim_max);
        assert_eq!(unsafe { libc::setrlimit(libc::RLIMIT_NOFILE, &limit) }, 0);
    }
    limit.rlim_cur
}

/// `target` is answered 200 within 2 s (a bound on starvation, not a timing: a worker lent to each slow
/// connection made it wait for their 10 s head deadline).
fn answered_promptly(address: SocketAddr, target: &str, beside: &str) {
    let start = Instant::now();
    let reply = get(address, target);
    assert_eq!(reply.status, 200, "{target} beside {beside}: {}", reply.text());
    assert!(start.elapsed() < Duration::from_secs(2), "{target} took {:?} beside {beside}", start.elapsed());
}

/// What the viewer sends on `stream` until it closes, or until `wait`.
fn read_reply(mut stream: TcpStream, wait: Duration) -> String {
    stream.set_read_timeout(Some(wait)).unwrap();
    let mut bytes = Vec::new();
    let _ = stream.read_to_end(&mut bytes);
    String::from_utf8_lossy(&bytes).into_owned()
}

#[test]
fn slow_idle_and_non_reading_clients_do_not_keep_a_request_waiting() {
    // This process and the viewer each hold a file per connection, past the viewer's 1024 at the end.
    let files = open_files_for(2048);
    assert!(files >= 2048, "ulimit -n allows {files} open files: this test holds over 1024 connections");
    let viewer = Viewer::start(&[]);
    let address = viewer.address;
    let info: serde_json::Value = serde_json::from_slice(&get(address, "/api/info").body).unwrap();
    let limit = info["limits"]["max_connections"].as_u64().unwrap() as usize;
    assert_eq!(limit, 1024);
    let connect = |sent: &[u8]| {
        let mut stream = TcpStream::connect(address).unwrap();
        stream.write_all(sent).unwrap();
        stream
    };
    // 100 idle, 100 sending a head a few bytes a second that never ends, 100 that never read their response.
    let idle: Vec<_> = (0..100).map(|_| connect(b"")).collect();
    let slow: Vec<_> = (0..100).map(|_| connect(b"GET /render.png?pose=")).collect();
    let readers: Vec<_> = (0..100).map(|_| connect(b"GET /viewer.js HTTP/1.1\r\n\r\n")).collect();
    let dripping = Arc::new(AtomicBool::new(true));
    let drip = {
        let dripping = dripping.clone();
        std::thread::spawn(move || {
            while dripping.load(Ordering::SeqCst) {
                for mut stream in &slow {
                    // Once answered (the head deadline), the viewer may close: later bytes fail, as they may.
                    let _ = stream.write_all(b"0,");
                }
                std::thread::sleep(Duration::from_millis(500));
            }
            slow
        })
    };
    std::thread::sleep(Duration::from_millis(1000));
    let beside = "300 slow, idle and non-reading connections";
    for target in ["/", "/api/info", "/input.png?scene=0&view=0"] {
        answered_promptly(address, target, beside);
    }
    let frame = get(address, "/render.png?size=40x28");
    assert_eq!(frame.status, 200, "{}", frame.text());
    // The slow heads still get their deadline: one line saying so.
    dripping.store(false, Ordering::SeqCst);
    let slow = drip.join().unwrap();
    for stream in slow.into_iter().chain(idle) {
        let late = read_reply(stream, Duration::from_secs(20));
        assert!(late.starts_with("HTTP/1.1 400") && late.ends_with("the head did not arrive in time\n"), "{late}");
    }
    for stream in readers {
        let script = read_reply(stream, Duration::from_secs(20));
        assert!(script.starts_with("HTTP/1.1 200") && script.contains("javascript"), "{}", &script[..80]);
    }
    // Past the limit, the oldest connection still sending its head makes room for the newest.
    std::thread::sleep(Duration::from_millis(1000));
    let crowd: Vec<_> = (0..limit + 24).map(|_| connect(b"")).collect();
    answered_promptly(address, "/", &format!("{} idle connections", crowd.len()));
    let mut crowd = crowd.into_iter();
    let oldest = read_reply(crowd.next().unwrap(), Duration::from_secs(20));
    assert!(oldest.starts_with("HTTP/1.1 503") && oldest.contains("made room"), "{oldest}");
    assert_eq!(read_reply(crowd.next_back().unwrap(), Duration::from_millis(200)), "", "the newest is kept");
    drop(crowd);
    assert_eq!(viewer.stop().0, 130);
}

#[test]
fn the_endpoint_renders_what_render_frame_renders_for_each_model_and_scene() {
    let dir = tempfile::tempdir().unwrap();
    let depth_model = golden("srt_k1_depth", "model.safetensors");
    let second_scene = "assets/scenes/scene-2000001.safetensors";
    let viewer = Viewer::start(&[
        "--model",
        BUNDLED_MODEL,
        "--model",
        &depth_model,
        "--scene",
        BUNDLED_SCENE,
        "--scene",
        second_scene,
    ]);
    let info: serde_json::Value = serde_json::from_slice(&get(viewer.address, "/api/info").body).unwrap();
    assert_eq!((info["models"].as_array().unwrap().len(), info["scenes"].as_array().unwrap().len()), (2, 2));
    assert_eq!(info["models"][1]["outputs"], serde_json::json!(["rgb", "depth"]));
    let pose = orbit_pose(140.0);
    let rows: Vec<f64> = pose.split(',').map(|v| v.parse().unwrap()).collect();
    let pose_file = dir.path().join("pose.json");
    let matrix: Vec<&[f64]> = rows.chunks(4).collect();
    std::fs::write(&pose_file, serde_json::json!({ "transform_matrix": matrix }).to_string()).unwrap();
    for (model, model_file, scene, scene_file) in
        [(0, BUNDLED_MODEL, 0, BUNDLED_SCENE), (1, depth_model.as_str(), 1, second_scene)]
    {
        let served = get(viewer.address, &format!("/render.png?pose={pose}&model={model}&scene={scene}"));
        assert_eq!(served.status, 200, "{}", served.text());
        let out = dir.path().join(format!("render_{model}.png"));
        let pose_arg = pose_file.display().to_string();
        let out_arg = out.display().to_string();
        let args = ["--model", model_file, "--scene", scene_file, "--pose", &pose_arg, "--out", &out_arg];
        let run = common::run(&root(), &args);
        assert_eq!(run.code, 0, "{}", run.stderr);
        assert_eq!(served.image(), Image::load_png(&out).unwrap(), "model {model}, scene {scene}");
    }
    let depth = get(viewer.address, &format!("/render.png?pose={pose}&model=1&output=depth")).image();
    assert!(depth.width() >= 80 && depth.height() > 60, "depth above its legend");
    let refused = get(viewer.address, "/render.png?model=0&output=depth");
    assert_eq!(
        (refused.status, refused.text().trim()),
        (400, "output: `depth` is not one model 0 renders (it renders rgb)")
    );
    assert_eq!(viewer.stop().0, 130);
}

#[test]
fn bad_serve_flags_fail_with_one_line() {
    let dir = tempfile::tempdir().unwrap();
    fails(dir.path(), &["--serve", "--port", "70000"], &["--port"]);
    fails(dir.path(), &["--serve", "--host", "not-an-address"], &["--host"]);
    fails(dir.path(), &["--serve", "--out", "x.png"], &["--out"]);
    fails(dir.path(), &["--serve", "--port", "0", "--model", "missing.safetensors"], &["--model missing.safetensors"]);
    fails(dir.path(), &["--serve", "--port", "0", "--scene", "missing"], &["--scene missing"]);
    let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = taken.local_addr().unwrap().port().to_string();
    fails(dir.path(), &["--serve", "--port", &port], &["--host 127.0.0.1 --port", &port]);
}
