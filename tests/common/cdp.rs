//! A headless Chromium driven over the Chrome DevTools Protocol, as much of it as the screen's
//! tests use: open a page, go to an address, evaluate JavaScript, press the mouse.
//!
//! Why not a crate: the CDP crates generate the whole protocol (chromiumoxide's took a minute
//! of every CI build, more than any other crate), while the tests send six commands. A command is
//! one JSON message over the browser's WebSocket; this is tokio-tungstenite and serde_json.

use std::collections::HashMap;
use std::io::BufRead;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use futures::{SinkExt, StreamExt};
use serde_json::{Value, json};
use tokio::sync::{mpsc, oneshot};
use tokio_tungstenite::tungstenite::Message;

/// How long a command may take before it is an error (a page's load included).
const COMMAND_TIMEOUT: Duration = Duration::from_secs(30);

/// Debian's `chromium`, or another Chromium or Chrome on the PATH.
pub fn chromium() -> Option<PathBuf> {
    ["chromium", "chromium-browser", "google-chrome", "google-chrome-stable"]
        .iter()
        .find_map(|name| {
            let out = Command::new("which").arg(name).output().ok()?;
            let path = String::from_utf8(out.stdout).ok()?.trim().to_string();
            (out.status.success() && !path.is_empty()).then(|| path.into())
        })
}

/// A command on its way to the browser, and where its answer goes.
struct Call {
    message: Value,
    reply: oneshot::Sender<Result<Value, String>>,
}

/// The connection to the browser: commands go out through the task that owns the WebSocket.
struct Connection {
    calls: mpsc::UnboundedSender<Call>,
    next_id: AtomicU64,
}

impl Connection {
    /// Sends `method` with `params` (to the page of `session`, if given) and waits for its result.
    async fn call(&self, session: Option<&str>, method: &str, params: Value) -> Result<Value, String> {
        let id = self.next_id.fetch_add(1, Ordering::Relaxed);
        let mut message = json!({"id": id, "method": method, "params": params});
        if let Some(session) = session {
            message["sessionId"] = session.into();
        }
        let (reply, answer) = oneshot::channel();
        self.calls
            .send(Call { message, reply })
            .map_err(|_| format!("{method}: the browser's connection is closed"))?;
        match tokio::time::timeout(COMMAND_TIMEOUT, answer).await {
            Ok(Ok(result)) => result.map_err(|e| format!("{method}: {e}")),
            Ok(Err(_)) => Err(format!("{method}: the browser's connection closed")),
            Err(_) => Err(format!("{method}: no answer within {COMMAND_TIMEOUT:?}")),
        }
    }
}

/// A headless Chromium of its own profile; killed when dropped.
pub struct Browser {
    child: Child,
    connection: Arc<Connection>,
}

impl Browser {
    /// Starts `chromium` headless with its profile in `profile`, a 1280 × 1400 window and the
    /// switches `args` (name, value) besides the usual ones of automation.
    pub async fn launch(chromium: &Path, profile: &Path, args: &[(&str, &str)]) -> Result<Browser, String> {
        let mut command = Command::new(chromium);
        command
            .args([
                "--headless",
                "--no-sandbox",
                "--disable-gpu",
                "--disable-dev-shm-usage",
                "--no-first-run",
                "--no-default-browser-check",
                "--disable-extensions",
                "--disable-sync",
                "--disable-background-networking",
                // The page's timers and frames must run as in a window in front.
                "--disable-background-timer-throttling",
                "--disable-backgrounding-occluded-windows",
                "--disable-renderer-backgrounding",
                "--mute-audio",
                "--hide-scrollbars",
                "--window-size=1280,1400",
                "--remote-debugging-port=0",
            ])
            .arg(format!("--user-data-dir={}", profile.display()))
            .args(args.iter().map(|(name, value)| format!("--{name}={value}")))
            .arg("about:blank")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped());
        let mut child = command.spawn().map_err(|e| format!("{}: {e}", chromium.display()))?;
        let stderr = child.stderr.take().ok_or("no stderr of Chromium")?;
        // The browser says where it listens on stderr; the rest of its stderr is drained so that
        // it never blocks on a full pipe.
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let mut tx = Some(tx);
            for line in std::io::BufReader::new(stderr).lines().map_while(Result::ok) {
                if let Some(at) = line.split("DevTools listening on ").nth(1)
                    && let Some(tx) = tx.take()
                {
                    let _ = tx.send(at.trim().to_string());
                }
            }
        });
        let started = Instant::now();
        let url = tokio::task::spawn_blocking(move || rx.recv_timeout(COMMAND_TIMEOUT))
            .await
            .map_err(|e| e.to_string())?
            .map_err(|_| {
                let _ = child.kill();
                format!("Chromium did not say where it listens within {:?}", started.elapsed())
            })?;
        let (socket, _) = tokio_tungstenite::connect_async(url.as_str())
            .await
            .map_err(|e| format!("Chromium's {url}: {e}"))?;
        let (calls, mut queued) = mpsc::unbounded_channel::<Call>();
        tokio::spawn(async move {
            let (mut out, mut incoming) = socket.split();
            let mut waiting: HashMap<u64, oneshot::Sender<Result<Value, String>>> = HashMap::new();
            loop {
                tokio::select! {
                    call = queued.recv() => {
                        let Some(Call { message, reply }) = call else { break };
                        let id = message["id"].as_u64().unwrap_or(0);
                        if let Err(e) = out.send(Message::Text(message.to_string().into())).await {
                            let _ = reply.send(Err(e.to_string()));
                            break;
                        }
                        waiting.insert(id, reply);
                    }
                    message = incoming.next() => {
                        let text = match message {
                            Some(Ok(Message::Text(text))) => text,
                            Some(Ok(_)) => continue,
                            _ => break,
                        };
                        // Events (no id) are not needed: a page's load is waited for by polling.
                        let Ok(message) = serde_json::from_str::<Value>(&text) else { continue };
                        if let Some(reply) = message["id"].as_u64().and_then(|id| waiting.remove(&id)) {
                            let result = match message.get("error") {
                                Some(error) => Err(error.to_string()),
                                None => Ok(message["result"].clone()),
                            };
                            let _ = reply.send(result);
                        }
                    }
                }
            }
        });
        Ok(Browser {
            child,
            connection: Arc::new(Connection {
                calls,
                next_id: AtomicU64::new(1),
            }),
        })
    }

    /// A new page (tab) at `url`, loaded.
    pub async fn new_page(&self, url: &str) -> Result<Page, String> {
        let target = self
            .connection
            .call(None, "Target.createTarget", json!({"url": "about:blank"}))
            .await?;
        let target = target["targetId"].as_str().ok_or("no targetId")?;
        let attached = self
            .connection
            .call(
                None,
                "Target.attachToTarget",
                json!({"targetId": target, "flatten": true}),
            )
            .await?;
        let page = Page {
            connection: Arc::clone(&self.connection),
            session: attached["sessionId"].as_str().ok_or("no sessionId")?.to_string(),
        };
        if url != "about:blank" {
            page.goto(url).await?;
        }
        Ok(page)
    }

    /// Closes the browser and waits for it to end.
    pub async fn close(mut self) {
        let _ = self.connection.call(None, "Browser.close", json!({})).await;
        let started = Instant::now();
        while started.elapsed() < Duration::from_secs(10) {
            if let Ok(Some(_)) = self.child.try_wait() {
                return;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for Browser {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

/// A page of the browser.
pub struct Page {
    connection: Arc<Connection>,
    session: String,
}

/// A mark left in a page's window: a navigation is done once a document without it has loaded.
const MARK: &str = "window.__left_by_the_test";

impl Page {
    async fn call(&self, method: &str, params: Value) -> Result<Value, String> {
        self.connection.call(Some(&self.session), method, params).await
    }

    /// The value of the JavaScript `expression` (a promise's once it settles); `Null` for
    /// `undefined`. An exception is an error with its text.
    pub async fn evaluate(&self, expression: impl AsRef<str>) -> Result<Value, String> {
        let expression = expression.as_ref();
        let result = self
            .call(
                "Runtime.evaluate",
                json!({"expression": expression, "returnByValue": true, "awaitPromise": true}),
            )
            .await?;
        if let Some(exception) = result.get("exceptionDetails") {
            let text = exception["exception"]["description"]
                .as_str()
                .or(exception["text"].as_str())
                .unwrap_or("an exception");
            return Err(format!("{expression}: {text}"));
        }
        Ok(result["result"].get("value").cloned().unwrap_or(Value::Null))
    }

    /// Runs `navigate` (a command that replaces the document) and waits until the new document
    /// has loaded.
    async fn replacing(&self, what: &str, navigate: impl AsyncFnOnce() -> Result<(), String>) -> Result<(), String> {
        self.evaluate(&format!("{MARK} = true")).await?;
        navigate().await?;
        let started = Instant::now();
        let loaded = format!("String({MARK} === undefined && document.readyState === 'complete')");
        loop {
            // During the switch of documents an evaluation may fail: it is asked again.
            if self.evaluate(&loaded).await.is_ok_and(|v| v == "true") {
                return Ok(());
            }
            if started.elapsed() > COMMAND_TIMEOUT {
                return Err(format!("{what}: not loaded within {COMMAND_TIMEOUT:?}"));
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }

    /// Goes to `url` and waits for its document to load.
    pub async fn goto(&self, url: impl AsRef<str>) -> Result<(), String> {
        let url = url.as_ref();
        self.replacing(url, async || {
            let went = self.call("Page.navigate", json!({"url": url})).await?;
            match went["errorText"].as_str() {
                Some(error) if !error.is_empty() => Err(format!("{url}: {error}")),
                _ => Ok(()),
            }
        })
        .await
    }

    /// Reloads the page and waits for it to load.
    pub async fn reload(&self) -> Result<(), String> {
        self.replacing("the reload", async || {
            self.call("Page.reload", json!({})).await.map(drop)
        })
        .await
    }

    /// Writes a PNG of the page's viewport to `path`.
    pub async fn screenshot(&self, path: &std::path::Path) -> Result<(), String> {
        use base64::Engine;
        let shot = self.call("Page.captureScreenshot", json!({"format": "png"})).await?;
        let data = shot["data"].as_str().ok_or("no screenshot data")?;
        let png = base64::engine::general_purpose::STANDARD
            .decode(data)
            .map_err(|e| format!("the screenshot's data: {e}"))?;
        std::fs::write(path, png).map_err(|e| format!("{}: {e}", path.display()))
    }

    /// Presses (or releases) the left mouse button at `at` (CSS pixels of the viewport), as a
    /// hand on the page would.
    pub async fn mouse(&self, at: (f64, f64), pressed: bool) -> Result<(), String> {
        let kind = if pressed { "mousePressed" } else { "mouseReleased" };
        self.call(
            "Input.dispatchMouseEvent",
            json!({"type": kind, "x": at.0, "y": at.1, "button": "left", "clickCount": 1}),
        )
        .await
        .map(drop)
    }
}
