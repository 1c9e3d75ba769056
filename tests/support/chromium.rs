//! Headless Chromium over WebDriver (chromedriver + fantoccini) for the browser tests
//! (`tests/browser.rs`, `tests/plans_ui.rs`, `tests/viewer.rs`).
//!
//! Needs Debian's `chromium` and `chromium-driver` (`/usr/bin/chromium`, `/usr/bin/chromedriver`;
//! override with `CHROMIUM` / `CHROMEDRIVER`). Without them a test FAILS when `CI=true` and
//! skips with a loud message otherwise.

use std::net::TcpListener;
use std::path::PathBuf;
use std::process::Stdio;
use std::time::{Duration, Instant};

use fantoccini::{Client, ClientBuilder};
use serde_json::json;

/// A WebDriver session on a fresh profile; chromedriver and the profile live as long as it.
pub struct Browser {
    pub client: Client,
    _driver: tokio::process::Child,
    _profile: tempfile::TempDir,
}

impl Browser {
    /// Ends the session and keeps a screenshot in the test's temp folder as `name`.
    pub async fn close(self, name: &str) {
        if let Ok(png) = self.client.screenshot().await {
            let path = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(name);
            std::fs::write(&path, png).unwrap();
            println!("screenshot: {}", path.display());
        }
        self.client.close().await.ok();
    }
}

fn tool(env: &str, default: &str) -> PathBuf {
    std::env::var_os(env)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(default))
}

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("a free port")
        .port()
}

async fn wait_for_port(port: u16) {
    let deadline = Instant::now() + Duration::from_secs(20);
    while tokio::net::TcpStream::connect(("127.0.0.1", port))
        .await
        .is_err()
    {
        assert!(
            Instant::now() < deadline,
            "chromedriver did not listen on {port} within 20 s"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

/// Whether the browser is installed: `false` means skip (said loudly); under `CI=true` a
/// missing browser fails the test instead.
pub fn available(test: &str) -> bool {
    let (chromium, driver) = (
        tool("CHROMIUM", "/usr/bin/chromium"),
        tool("CHROMEDRIVER", "/usr/bin/chromedriver"),
    );
    if chromium.is_file() && driver.is_file() {
        return true;
    }
    let msg = format!(
        "headless Chromium is not installed ({} / {}): apt-get install -y chromium chromium-driver",
        chromium.display(),
        driver.display()
    );
    if std::env::var("CI").is_ok_and(|v| v == "true") {
        panic!("{msg}");
    }
    eprintln!("\n!!!!!!!! SKIPPING {test}: {msg} !!!!!!!!\n");
    false
}

/// Starts chromedriver and a headless Chromium session with a `width,height` window and any
/// `extra` Chromium flags (call [`available`] first).
pub async fn launch(window: &str, extra: &[&str]) -> Browser {
    let port = free_port();
    let driver = tokio::process::Command::new(tool("CHROMEDRIVER", "/usr/bin/chromedriver"))
        .arg(format!("--port={port}"))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .kill_on_drop(true)
        .spawn()
        .expect("chromedriver starts");
    wait_for_port(port).await;
    let profile = tempfile::tempdir().unwrap();
    // Without the background-networking flags Chromium keeps calling out of a closed network.
    let mut args: Vec<String> = [
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--disable-dev-shm-usage",
    ]
    .iter()
    .chain(extra)
    .map(|s| s.to_string())
    .collect();
    args.push(format!("--window-size={window}"));
    args.push(format!("--user-data-dir={}", profile.path().display()));
    let caps = json!({
        "browserName": "chrome",
        "goog:chromeOptions": {
            "binary": tool("CHROMIUM", "/usr/bin/chromium"),
            "args": args,
        },
    });
    let client = ClientBuilder::new(hyper_util::client::legacy::connect::HttpConnector::new())
        .capabilities(caps.as_object().unwrap().clone())
        .connect(&format!("http://127.0.0.1:{port}"))
        .await
        .expect("a WebDriver session");
    Browser {
        client,
        _driver: driver,
        _profile: profile,
    }
}
