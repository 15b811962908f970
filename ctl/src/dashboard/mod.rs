//! `foc-ctl dashboard`: a local web page for a drive on serial, TCP or the
//! simulated drive (`--simulate`). The page (ctl/web/, with uPlot vendored
//! from the npm registry) is built into the binary; nothing is fetched at
//! run time.
//!
//! One thread owns the link ([`link::Link`]): it streams telemetry into a
//! buffer and runs the page's jobs. The HTTP server answers the page:
//!
//! | request | answer |
//! |---|---|
//! | `GET /`, `/app.js`, `/app.css`, `/uPlot.*` | the page |
//! | `GET /api/signals` | the plottable signals and their units |
//! | `GET /api/samples?since=N` | the samples from index N on (device time) |
//! | `GET /api/status` | mode, faults (what each means, what to do), calibration progress |
//! | `POST /api/console` (a command line) | a foc-ctl command's output |
//! | `POST /api/calibrate` (`offsets` or `identification`) | started, or the refusal |
//! | `POST /api/sensor-check`, `POST /api/tune` | the wizard's steps |
//! | `POST /api/disable` | a running job stopped, then the drive disabled |
//! | `POST /api/rate` (Hz) | the stream's rate, or the refusal |
//! | `GET /api/config` | the configuration tree: each key's value, unit, range and meaning |
//! | `POST /api/config` (`{"key", "value"}`) | the key changed and applied, or the refusal |
//! | `GET /api/scope` | the scope's state, and its capture when done |
//! | `POST /api/motor` (`{"file", "values"}`) | the wizard's motor step: a motor file or nameplate values applied |

mod config;
mod faults;
mod link;
mod wizard;

use crate::cli::DashboardArgs;
use crate::{connect, Cli};
use foc_ctl::sim::{Options, SimDevice, SimServer};
use foc_ctl::Client;
use foc_protocol::message::Calibration;
use link::{Job, Link, Shared, SIGNALS};
use serde_json::{json, Value};
use std::io::Read;
use std::sync::mpsc::{self, Sender};
use std::sync::Arc;
use std::time::Duration;
use tiny_http::{Header, Method, Request, Response, Server};

const INDEX: &str = include_str!("../../web/index.html");
const APP_JS: &str = include_str!("../../web/app.js");
const APP_CSS: &str = include_str!("../../web/app.css");
const UPLOT_JS: &str = include_str!("../../web/vendor/uplot/uPlot.iife.min.js");
const UPLOT_CSS: &str = include_str!("../../web/vendor/uplot/uPlot.min.css");

/// Longest a page waits for a job (the identification is followed in the
/// status, not waited for); the link thread drops a job that waited longer
/// than [`link::JOB_EXPIRES`].
const JOB_WAIT: Duration = Duration::from_secs(60);

/// `foc-ctl dashboard`: serve the page until killed.
pub(super) fn serve(cli: &Cli, a: &DashboardArgs) -> crate::CliResult {
    // The simulated drive, when asked: served on a local port of its own
    // (other foc-ctl commands may connect to it too).
    let _sim;
    if !(a.time_scale > 0.0 && a.time_scale <= 100.0) {
        return Err(format!("--time-scale {} is outside (0, 100]", a.time_scale).into());
    }
    let client = if a.simulate {
        let setup = match &a.motor {
            Some(p) => foc_bench::mission::Setup::load(p)
                .map_err(|e| format!("motor file {}: {e}", p.display()))?,
            None => foc_bench::scope_step::emulated_setup(),
        };
        let dev = SimDevice::new(Options::simulator(setup));
        let server = SimServer::spawn_scaled(
            std::net::TcpListener::bind("127.0.0.1:0")?,
            dev,
            a.time_scale,
        )?;
        let addr = server.addr();
        say_err!("simulated drive on {addr} (foc-ctl --tcp {addr} ... works too)");
        _sim = Some(server);
        let mut c = Client::connect_tcp(addr)?;
        c.set_timeout(Duration::from_millis(cli.timeout_ms));
        c
    } else {
        _sim = None;
        connect(cli)?
    };
    let server =
        Server::http(&a.listen).map_err(|e| format!("cannot listen on {}: {e}", a.listen))?;
    let shared = Arc::new(Shared::default());
    let (jobs, rx) = mpsc::channel::<(Job, std::time::Instant, Sender<Value>)>();
    let link = Link::new(client, shared.clone(), a.rate);
    std::thread::spawn(move || link.run(rx));
    say_err!("dashboard on http://{} (Ctrl-C to stop)", a.listen);
    for req in server.incoming_requests() {
        let jobs = jobs.clone();
        let shared = shared.clone();
        // One thread per request: a long job does not hold up the samples.
        std::thread::spawn(move || answer(req, &shared, &jobs));
    }
    Ok(())
}

/// Answer one request.
fn answer(
    mut req: Request,
    shared: &Shared,
    jobs: &Sender<(Job, std::time::Instant, Sender<Value>)>,
) {
    let url = req.url().to_string();
    let (path, query) = url.split_once('?').unwrap_or((url.as_str(), ""));
    let mut body = String::new();
    if *req.method() == Method::Post {
        let _ = req.as_reader().take(64 * 1024).read_to_string(&mut body);
    }
    let r = match (req.method(), path) {
        (Method::Get, "/") => text(INDEX, "text/html; charset=utf-8"),
        (Method::Get, "/app.js") => text(APP_JS, "text/javascript"),
        (Method::Get, "/app.css") => text(APP_CSS, "text/css"),
        (Method::Get, "/uPlot.iife.min.js") => text(UPLOT_JS, "text/javascript"),
        (Method::Get, "/uPlot.min.css") => text(UPLOT_CSS, "text/css"),
        (Method::Get, "/api/signals") => {
            let s: Vec<Value> = SIGNALS
                .iter()
                .map(|(n, u)| json!({"name": n, "unit": u}))
                .collect();
            json_response(&json!(s))
        }
        (Method::Get, "/api/samples") => {
            if let Ok(mut g) = shared.page_seen.lock() {
                *g = Some(std::time::Instant::now());
            }
            let since = query
                .split('&')
                .find_map(|kv| kv.strip_prefix("since="))
                .and_then(|v| v.parse::<u64>().ok())
                .unwrap_or(0);
            let v = shared
                .samples
                .lock()
                .map(|s| s.since(since, 20_000))
                .unwrap_or(Value::Null);
            json_response(&v)
        }
        (Method::Get, "/api/status") => {
            let v = shared
                .status
                .lock()
                .map(|s| s.clone())
                .unwrap_or(Value::Null);
            json_response(&v)
        }
        (Method::Post, "/api/console") => job(jobs, Job::Console(body.trim().to_string())),
        (Method::Post, "/api/calibrate") => match body.trim() {
            "offsets" => job(jobs, Job::Calibrate(Calibration::Offsets)),
            "identification" => job(jobs, Job::Calibrate(Calibration::Identification)),
            other => json_response(&json!({"ok": false, "error": format!("no routine `{other}`")})),
        },
        (Method::Get, "/api/config") => job(jobs, Job::ConfigTree),
        (Method::Post, "/api/config") => match serde_json::from_str::<Value>(&body) {
            Ok(v) => match (
                v.get("key").and_then(Value::as_str),
                v.get("value").and_then(Value::as_str),
            ) {
                (Some(k), Some(x)) => job(jobs, Job::ConfigSet(k.to_string(), x.to_string())),
                _ => json_response(
                    &json!({"ok": false, "error": "give {\"key\": ..., \"value\": ...}"}),
                ),
            },
            Err(e) => json_response(&json!({"ok": false, "error": e.to_string()})),
        },
        (Method::Get, "/api/scope") => job(jobs, Job::ScopeData),
        (Method::Post, "/api/motor") => match serde_json::from_str::<Value>(&body) {
            Ok(v) => job(jobs, motor_job(&v)),
            Err(e) => json_response(&json!({"ok": false, "error": e.to_string()})),
        },
        (Method::Post, "/api/sensor-check") => job(jobs, Job::SensorCheck),
        (Method::Post, "/api/disable") => {
            // A running job stops at its next check; then the bridge goes off.
            shared
                .abort
                .store(true, std::sync::atomic::Ordering::Relaxed);
            job(jobs, Job::Disable)
        }
        (Method::Post, "/api/tune") => job(jobs, Job::Tune),
        (Method::Post, "/api/rate") => match body.trim().parse::<f32>() {
            Ok(hz) => job(jobs, Job::SetRate(hz)),
            Err(_) => json_response(
                &json!({"ok": false, "error": format!("`{}` is not a rate in Hz", body.trim())}),
            ),
        },
        _ => text("not found", "text/plain").with_status_code(404),
    };
    let _ = req.respond(r);
}

/// The wizard's motor step from the page's `{"file": text, "values":
/// {key: value}}` (empty ones left out).
fn motor_job(v: &Value) -> Job {
    let file = v
        .get("file")
        .and_then(Value::as_str)
        .filter(|t| !t.trim().is_empty())
        .map(str::to_string);
    let pairs = v
        .get("values")
        .and_then(Value::as_object)
        .map(|m| {
            m.iter()
                .filter_map(|(k, x)| x.as_str().map(|s| (k.clone(), s.trim().to_string())))
                .filter(|(_, s)| !s.is_empty())
                .collect()
        })
        .unwrap_or_default();
    Job::Motor(file, pairs)
}

/// Run `j` on the link thread and wait for its answer.
fn job(
    jobs: &Sender<(Job, std::time::Instant, Sender<Value>)>,
    j: Job,
) -> Response<std::io::Cursor<Vec<u8>>> {
    let (tx, rx) = mpsc::channel();
    if jobs.send((j, std::time::Instant::now(), tx)).is_err() {
        return json_response(&json!({"ok": false, "error": "the link thread has stopped"}));
    }
    match rx.recv_timeout(JOB_WAIT) {
        Ok(v) => json_response(&v),
        Err(_) => json_response(&json!({"ok": false, "error": "no answer from the link in time"})),
    }
}

fn text(s: &str, mime: &str) -> Response<std::io::Cursor<Vec<u8>>> {
    let mut r = Response::from_string(s);
    if let Ok(h) = Header::from_bytes(&b"Content-Type"[..], mime.as_bytes()) {
        r.add_header(h);
    }
    if let Ok(h) = Header::from_bytes(&b"Cache-Control"[..], &b"no-store"[..]) {
        r.add_header(h);
    }
    r
}

fn json_response(v: &Value) -> Response<std::io::Cursor<Vec<u8>>> {
    text(&v.to_string(), "application/json")
}
