//! Headless Chromium driven through the DevTools protocol over
//! `--remote-debugging-pipe` (JSON messages ended by a NUL byte on
//! descriptors 3 and 4): evaluate JavaScript in the page, take a screenshot.
//! The pipe needs no WebSocket client; the descriptors are two FIFOs that
//! `sh` opens as 3 and 4 before it execs Chromium (no `pre_exec`, which
//! would need unsafe code).

use std::fs::File;
use std::io::{BufRead, BufReader, Write};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::{json, Value};

/// The browser, attached to its first page.
pub struct Chromium {
    child: Child,
    to: File,
    from: BufReader<File>,
    next_id: u64,
    session: String,
    _profile: tempfile::TempDir,
}

impl Chromium {
    /// Starts `/usr/bin/chromium` headless on `url`; None (after one
    /// skip line naming the package) when it is not installed.
    pub fn start(url: &str) -> Option<Self> {
        if !crate::skip::have("chromium", "chromium", "the page test") {
            return None;
        }
        let profile = tempfile::tempdir().unwrap();
        let (to_path, from_path) = (profile.path().join("in"), profile.path().join("out"));
        for p in [&to_path, &from_path] {
            nix::unistd::mkfifo(p, nix::sys::stat::Mode::S_IRWXU).unwrap();
        }
        let child = Command::new("sh")
            .arg("-c")
            .arg("exec 3<\"$1\" 4>\"$2\"; shift 2; exec \"$@\"")
            .arg("sh")
            .arg(&to_path)
            .arg(&from_path)
            .args(["chromium", "--headless"])
            .args(crate::browser::CHROMIUM_QUIET)
            .args(["--remote-debugging-pipe", "--window-size=1280,1500"])
            .arg(format!(
                "--user-data-dir={}",
                profile.path().join("profile").display()
            ))
            .arg(url)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        // Opening a FIFO waits for the other side: sh opens "in" for reading first.
        let to = std::fs::OpenOptions::new()
            .write(true)
            .open(&to_path)
            .unwrap();
        let from = BufReader::new(File::open(&from_path).unwrap());
        let mut c = Self {
            child,
            to,
            from,
            next_id: 0,
            session: String::new(),
            _profile: profile,
        };
        c.attach();
        Some(c)
    }

    fn attach(&mut self) {
        let deadline = Instant::now() + Duration::from_secs(60);
        let target = loop {
            let targets = self.call(None, "Target.getTargets", json!({}));
            let page = targets["targetInfos"]
                .as_array()
                .into_iter()
                .flatten()
                .find(|t| t["type"] == "page")
                .and_then(|t| t["targetId"].as_str().map(str::to_owned));
            if let Some(t) = page {
                break t;
            }
            assert!(Instant::now() < deadline, "Chromium opened no page");
            std::thread::sleep(Duration::from_millis(200));
        };
        let attached = self.call(
            None,
            "Target.attachToTarget",
            json!({"targetId": target, "flatten": true}),
        );
        self.session = attached["sessionId"].as_str().unwrap().to_owned();
    }

    /// Sends one command and returns its result (events are skipped).
    fn call(&mut self, session: Option<&str>, method: &str, params: Value) -> Value {
        self.try_call(session, method, params)
            .unwrap_or_else(|e| panic!("{method}: {e}"))
    }

    /// [`Self::call`], with Chromium's error reply as an error.
    fn try_call(
        &mut self,
        session: Option<&str>,
        method: &str,
        params: Value,
    ) -> Result<Value, Value> {
        self.next_id += 1;
        let id = self.next_id;
        let mut msg = json!({"id": id, "method": method, "params": params});
        if let Some(s) = session {
            msg["sessionId"] = json!(s);
        }
        let mut bytes = msg.to_string().into_bytes();
        bytes.push(0);
        self.to.write_all(&bytes).unwrap();
        loop {
            let mut buf = Vec::new();
            let n = self.from.read_until(0, &mut buf).unwrap();
            assert!(n > 0, "Chromium closed the DevTools pipe");
            buf.pop();
            let reply: Value = serde_json::from_slice(&buf).unwrap();
            if reply["id"] == id {
                return match reply["error"].is_null() {
                    true => Ok(reply["result"].clone()),
                    false => Err(reply["error"].clone()),
                };
            }
        }
    }

    /// Evaluates `expression` in the page (awaiting a promise) and returns its value.
    pub fn eval(&mut self, expression: &str) -> Value {
        self.try_eval(expression)
            .unwrap_or_else(|e| panic!("Runtime.evaluate: {e}"))
    }

    /// [`Self::eval`], with Chromium's error reply (the page navigated
    /// while it ran, say) as an error.
    fn try_eval(&mut self, expression: &str) -> Result<Value, Value> {
        let session = self.session.clone();
        let r = self.try_call(
            Some(&session),
            "Runtime.evaluate",
            json!({"expression": expression, "returnByValue": true, "awaitPromise": true}),
        )?;
        assert!(
            r["exceptionDetails"].is_null(),
            "{expression}: {}",
            r["exceptionDetails"]
        );
        Ok(r["result"]["value"].clone())
    }

    /// Evaluates `expression` until it is true, at most `timeout`. An
    /// evaluation the page's own navigation cut off (a page that moves on,
    /// as the viewer's file does to its server) counts as not yet.
    pub fn wait_for(&mut self, expression: &str, timeout: Duration) {
        let deadline = Instant::now() + timeout;
        loop {
            match self.try_eval(expression) {
                Ok(Value::Bool(true)) => return,
                Ok(_) => {}
                Err(e) if e["message"] == "Inspected target navigated or closed" => {}
                Err(e) => panic!("Runtime.evaluate {expression}: {e}"),
            }
            assert!(
                Instant::now() < deadline,
                "timed out waiting for {expression}"
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// Writes a PNG screenshot of the page to `path`.
    pub fn screenshot(&mut self, path: &Path) {
        use base64::Engine;
        let session = self.session.clone();
        let r = self.call(
            Some(&session),
            "Page.captureScreenshot",
            json!({"format": "png"}),
        );
        let png = base64::engine::general_purpose::STANDARD
            .decode(r["data"].as_str().unwrap())
            .unwrap();
        std::fs::write(path, png).unwrap();
    }
}

impl Drop for Chromium {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}
