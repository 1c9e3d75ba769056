//! Request-body limits, separate from the request timeout (issue 20): a declared length over
//! the limit is 413 before the body is read; a body that stalls is 408 after the idle time.
//! Raw loopback TCP, so the client can declare one length and send another.

use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

use crate::helpers::{TestApp, spawn_app_with};

/// Sends `head` (request line and headers, without the blank line) and `body`, keeps the
/// connection open without sending more, and returns what the server answers within `wait`
/// (until it closes the connection or the wait ends).
async fn send_and_stall(base_url: &str, head: &str, body: &[u8], wait: Duration) -> String {
    let addr = base_url.trim_start_matches("http://");
    let mut tcp = TcpStream::connect(addr).await.unwrap();
    tcp.write_all(format!("{head}\r\n\r\n").as_bytes())
        .await
        .unwrap();
    tcp.write_all(body).await.unwrap();
    tcp.flush().await.unwrap();
    let mut answer = Vec::new();
    let mut buf = [0u8; 4096];
    let deadline = tokio::time::Instant::now() + wait;
    loop {
        match tokio::time::timeout_at(deadline, tcp.read(&mut buf)).await {
            Ok(Ok(0)) | Ok(Err(_)) | Err(_) => break,
            Ok(Ok(n)) => {
                answer.extend_from_slice(&buf[..n]);
                // The problem document is small; stop once it is complete.
                let text = String::from_utf8_lossy(&answer);
                if let Some((_, b)) = text.split_once("\r\n\r\n")
                    && b.trim_end().ends_with('}')
                {
                    break;
                }
            }
        }
    }
    String::from_utf8_lossy(&answer).into_owned()
}

/// Objects stored (the seeded everyday objects included).
async fn object_count(app: &TestApp) -> usize {
    let list: serde_json::Value = app.get("/v1/objects").await.json().await.unwrap();
    list.as_array().expect("a list of objects").len()
}

fn post_head(path: &str, length: usize) -> String {
    format!(
        "POST {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n\
         Content-Length: {length}"
    )
}

#[tokio::test]
async fn a_declared_length_over_the_limit_is_413_before_the_body_arrives() {
    // A long idle time: if the server waited for the body, no answer would come in the wait.
    let app = spawn_app_with(|c| {
        c.body_limit = 4096;
        c.body_idle_timeout_ms = 120_000;
    })
    .await;
    let before = object_count(&app).await;
    let answer = send_and_stall(
        &app.base_url,
        &post_head("/v1/objects", 2 * 4096),
        b"{\"name\":",
        Duration::from_secs(10),
    )
    .await;
    assert!(answer.starts_with("HTTP/1.1 413"), "{answer}");
    assert!(answer.contains("application/problem+json"), "{answer}");
    assert!(
        answer.contains("urn:reachgrasp:problem:payload-too-large"),
        "{answer}"
    );
    assert!(answer.contains("8192 bytes"), "{answer}");
    // Nothing was stored, and the service answers the next request.
    assert_eq!(object_count(&app).await, before);
}

#[tokio::test]
async fn a_body_that_stalls_is_408_after_the_idle_time_not_a_5xx() {
    // Request timeout 60 s (the default): a stall must not wait for it, nor become its 503.
    let app = spawn_app_with(|c| c.body_idle_timeout_ms = 300).await;
    let before = object_count(&app).await;
    // Part of the body, then nothing.
    let answer = send_and_stall(
        &app.base_url,
        &post_head("/v1/objects", 200),
        b"{\"name\": \"ball\", ",
        Duration::from_secs(10),
    )
    .await;
    assert!(answer.starts_with("HTTP/1.1 408"), "{answer}");
    assert!(answer.contains("application/problem+json"), "{answer}");
    assert!(
        answer.contains("urn:reachgrasp:problem:body-timeout"),
        "{answer}"
    );
    // Headers only, no byte of the body.
    let answer = send_and_stall(
        &app.base_url,
        &post_head("/v1/_test/jobs/sleep", 40),
        b"",
        Duration::from_secs(10),
    )
    .await;
    assert!(answer.starts_with("HTTP/1.1 408"), "{answer}");
    assert!(
        answer.contains("urn:reachgrasp:problem:body-timeout"),
        "{answer}"
    );
    // Nothing started or stored, and a prompt request is served as usual.
    let jobs: serde_json::Value = app.get("/v1/jobs").await.json().await.unwrap();
    assert_eq!(jobs["items"].as_array().map(Vec::len), Some(0), "{jobs}");
    assert_eq!(object_count(&app).await, before);
    let res = app
        .post_json(
            "/v1/_test/jobs/sleep",
            &serde_json::json!({"steps": 1, "step_ms": 1}),
        )
        .await;
    assert_eq!(res.status(), 202);
}

#[tokio::test]
async fn a_slow_but_steady_body_within_the_limit_is_accepted() {
    // Chunks arrive more often than the idle time: the body is read in full.
    let app = spawn_app_with(|c| c.body_idle_timeout_ms = 2_000).await;
    let body = br#"{"steps": 1, "step_ms": 1}"#;
    let addr = app.base_url.trim_start_matches("http://").to_owned();
    let mut tcp = TcpStream::connect(addr).await.unwrap();
    let head = post_head("/v1/_test/jobs/sleep", body.len());
    tcp.write_all(format!("{head}\r\nConnection: close\r\n\r\n").as_bytes())
        .await
        .unwrap();
    for chunk in body.chunks(9) {
        tokio::time::sleep(Duration::from_millis(100)).await;
        tcp.write_all(chunk).await.unwrap();
    }
    let mut answer = String::new();
    tokio::time::timeout(Duration::from_secs(10), tcp.read_to_string(&mut answer))
        .await
        .expect("an answer within 10 s")
        .unwrap();
    assert!(answer.starts_with("HTTP/1.1 202"), "{answer}");
}
