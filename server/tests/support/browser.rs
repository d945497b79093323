//! A real browser for the web view's tests: Debian's `chromium`, headless, driven over the W3C
//! WebDriver protocol through Debian's `chromedriver` on a loopback port of its own (both come
//! from one source package, so their versions match; `./dev test` installs them).
//!
//! The client is the dozen WebDriver commands the tests use, over `ureq`, which the workspace
//! already has: a WebDriver crate (`fantoccini`) would add ~50 crates and change the features
//! of `syn`, which rebuilds `bindgen` and RocksDB (~15 minutes) and makes the test build differ
//! from the service's.

use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::{Value, json};

use super::free_port;

/// The viewport of every test: the smaller screen the web view is made for.
pub const WIDTH: u32 = 1280;
/// See [`WIDTH`].
pub const HEIGHT: u32 = 800;

/// The key of an element reference in WebDriver answers.
const ELEMENT: &str = "element-6066-11e4-a52e-4f735466cecf";

/// A chromedriver with one headless chromium session; dropping it ends both.
pub struct Browser {
    driver: Child,
    session: String,
    agent: ureq::Agent,
    _profile: tempfile::TempDir,
}

fn find(program: &str, debian_path: &str) -> PathBuf {
    if Path::new(debian_path).exists() {
        return debian_path.into();
    }
    std::env::var_os("PATH")
        .and_then(|paths| {
            std::env::split_paths(&paths)
                .map(|d| d.join(program))
                .find(|p| p.exists())
        })
        .unwrap_or_else(|| {
            panic!(
                "{program} is missing: the browser tests need Debian's chromium and \
                 chromium-driver (`./dev test` installs them)"
            )
        })
}

impl Browser {
    /// Starts chromedriver and a headless chromium at [`WIDTH`]×[`HEIGHT`].
    pub fn start() -> Self {
        let driver_bin = find("chromedriver", "/usr/bin/chromedriver");
        let chromium = find("chromium", "/usr/bin/chromium");
        let port = free_port();
        let profile = tempfile::tempdir().expect("profile directory");
        // Chromium's own temporary directories (`org.chromium.Chromium.scoped_dir.*`) go inside
        // the profile's, removed with it: in /tmp they were left behind by every run.
        let scratch = profile.path().join("tmp");
        std::fs::create_dir_all(&scratch).expect("a temporary directory");
        let driver = Command::new(driver_bin)
            .env("TMPDIR", &scratch)
            .arg(format!("--port={port}"))
            .arg("--allowed-ips=127.0.0.1")
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("start chromedriver");
        let deadline = Instant::now() + Duration::from_secs(30);
        while TcpStream::connect(("127.0.0.1", port)).is_err() {
            assert!(Instant::now() < deadline, "chromedriver did not listen");
            std::thread::sleep(Duration::from_millis(50));
        }
        let args = [
            "--headless=new".to_owned(),
            "--no-sandbox".to_owned(),
            "--disable-gpu".to_owned(),
            "--disable-dev-shm-usage".to_owned(),
            "--disable-background-networking".to_owned(),
            "--disable-component-update".to_owned(),
            "--disable-sync".to_owned(),
            "--no-first-run".to_owned(),
            "--force-device-scale-factor=1".to_owned(),
            format!("--window-size={WIDTH},{HEIGHT}"),
            format!("--user-data-dir={}", profile.path().display()),
        ];
        let agent: ureq::Agent = ureq::Agent::config_builder()
            .http_status_as_error(false)
            .timeout_global(Some(Duration::from_secs(300)))
            .build()
            .into();
        let base = format!("http://127.0.0.1:{port}");
        let mut browser = Self {
            driver,
            session: base.clone(),
            agent,
            _profile: profile,
        };
        let created = browser.command(
            "POST",
            "/session",
            Some(json!({"capabilities": {"alwaysMatch": {
                "browserName": "chrome",
                "goog:chromeOptions": {"binary": chromium, "args": args},
                "timeouts": {"script": 120_000}
            }}})),
        );
        let id = created["sessionId"]
            .as_str()
            .unwrap_or_else(|| panic!("no session: {created}"));
        browser.session = format!("{base}/session/{id}");
        browser
    }

    /// One WebDriver command; `path` is under the session (or the driver for `/session`).
    fn command(&self, method: &str, path: &str, body: Option<Value>) -> Value {
        let url = format!("{}{path}", self.session);
        let mut r = match (method, body) {
            ("GET", _) => self.agent.get(&url).call(),
            ("DELETE", _) => self.agent.delete(&url).call(),
            (_, body) => self
                .agent
                .post(&url)
                .header("Content-Type", "application/json")
                .send(body.unwrap_or_else(|| json!({})).to_string().as_bytes()),
        }
        .unwrap_or_else(|e| panic!("WebDriver {method} {path}: {e}"));
        let text = r.body_mut().read_to_string().unwrap_or_default();
        let v: Value = serde_json::from_str(&text).unwrap_or(Value::Null);
        assert!(
            r.status().is_success(),
            "WebDriver {method} {path}: {} {text}",
            r.status()
        );
        v.get("value").cloned().unwrap_or(Value::Null)
    }

    /// Loads `url`.
    pub fn goto(&self, url: &str) {
        self.command("POST", "/url", Some(json!({"url": url})));
    }

    /// Resizes the window.
    pub fn resize(&self, width: u32, height: u32) {
        self.command(
            "POST",
            "/window/rect",
            Some(json!({"width": width, "height": height})),
        );
    }

    /// Runs `script` (a function body: `return ...`) in the page.
    pub fn js(&self, script: &str) -> Value {
        self.command(
            "POST",
            "/execute/sync",
            Some(json!({"script": script, "args": []})),
        )
    }

    /// Runs `script`, which calls its last argument with the result, and waits for it.
    pub fn js_async(&self, script: &str) -> Value {
        self.command(
            "POST",
            "/execute/async",
            Some(json!({"script": script, "args": []})),
        )
    }

    /// Polls `script` until it returns something other than null, false or undefined.
    pub fn until(&self, what: &str, timeout: Duration, script: &str) -> Value {
        let deadline = Instant::now() + timeout;
        loop {
            let v = self.js(script);
            if !(v.is_null() || v == Value::Bool(false)) {
                return v;
            }
            assert!(Instant::now() < deadline, "timed out waiting for {what}");
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    fn element(&self, css: &str) -> String {
        let v = self.command(
            "POST",
            "/element",
            Some(json!({"using": "css selector", "value": css})),
        );
        v[ELEMENT]
            .as_str()
            .unwrap_or_else(|| panic!("no element {css}: {v}"))
            .to_owned()
    }

    /// Clicks the element `css` selects.
    pub fn click(&self, css: &str) {
        let e = self.element(css);
        self.command("POST", &format!("/element/{e}/click"), None);
    }

    /// Types `text` into the element `css` selects, after clearing it (file inputs take a path).
    pub fn type_into(&self, css: &str, text: &str) {
        let e = self.element(css);
        let ty = self.command("GET", &format!("/element/{e}/attribute/type"), None);
        if ty != "file" {
            self.command("POST", &format!("/element/{e}/clear"), None);
        }
        self.command(
            "POST",
            &format!("/element/{e}/value"),
            Some(json!({"text": text})),
        );
    }

    /// Chooses the option of value `value` in the `select` element `css` selects, as a user
    /// choosing it does (the element's `change` event fires).
    pub fn choose(&self, css: &str, value: &str) {
        let found = self.command(
            "POST",
            "/execute/sync",
            Some(json!({
                "script": "const s = document.querySelector(arguments[0]); \
                           if (!s || ![...s.options].some(o => o.value === arguments[1])) return false; \
                           s.focus(); s.value = arguments[1]; s.dispatchEvent(new Event('input', {bubbles: true})); \
                           s.dispatchEvent(new Event('change', {bubbles: true})); return true",
                "args": [css, value]
            })),
        );
        assert_eq!(found, Value::Bool(true), "no option {value:?} in {css}");
    }

    /// Writes a PNG of the window to the screenshot directory ([`shots_dir`]) as `name.png`.
    pub fn shot(&self, name: &str) -> PathBuf {
        let b64 = self.command("GET", "/screenshot", None);
        let png = base64_decode(b64.as_str().expect("a base64 screenshot"));
        assert!(png.starts_with(b"\x89PNG\r\n\x1a\n"), "a PNG screenshot");
        let dir = shots_dir();
        std::fs::create_dir_all(&dir).expect("screenshot directory");
        let path = dir.join(format!("{name}.png"));
        std::fs::write(&path, png).expect("write screenshot");
        eprintln!("screenshot: {}", path.display());
        path
    }
}

/// `DYKNOW_SCREENSHOTS` when set (`./dev screenshots` sets it to `docs/screenshots`), otherwise
/// a directory in Cargo's target directory.
pub fn shots_dir() -> PathBuf {
    std::env::var_os("DYKNOW_SCREENSHOTS").map_or_else(
        || Path::new(env!("CARGO_TARGET_TMPDIR")).join("ui-screenshots"),
        PathBuf::from,
    )
}

/// Standard base64 (RFC 4648, padded), as WebDriver sends screenshots.
fn base64_decode(s: &str) -> Vec<u8> {
    let value = |c: u8| match c {
        b'A'..=b'Z' => c - b'A',
        b'a'..=b'z' => c - b'a' + 26,
        b'0'..=b'9' => c - b'0' + 52,
        b'+' => 62,
        b'/' => 63,
        _ => panic!("not base64: {c}"),
    };
    let bytes: Vec<u8> = s.bytes().filter(|c| !c.is_ascii_whitespace()).collect();
    let mut out = Vec::with_capacity(bytes.len() / 4 * 3);
    for chunk in bytes.chunks(4) {
        let data: Vec<u8> = chunk
            .iter()
            .take_while(|&&c| c != b'=')
            .map(|&c| value(c))
            .collect();
        let n = data
            .iter()
            .enumerate()
            .fold(0u32, |n, (i, &v)| n | (u32::from(v) << (18 - 6 * i)));
        for i in 0..data.len().saturating_sub(1) {
            out.push((n >> (16 - 8 * i)) as u8);
        }
    }
    out
}

impl Drop for Browser {
    fn drop(&mut self) {
        // Ending the session makes chromedriver close chromium; then the driver goes.
        let _ = self.agent.delete(&self.session).call();
        let _ = self.driver.kill();
        let _ = self.driver.wait();
    }
}
