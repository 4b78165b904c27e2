//! A hostile or broken camera on the THETA's address (issue 20, D2, D5, D6): answers that
//! announce or send more than any THETA picture, and redirects to another host. Each must end
//! in an error that says so, never in an abort or in another host's bytes.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::time::Duration;

use brdfd_theta::{HttpTimeouts, OscClient, ThetaError};

/// Serves every connection with `answer(request line)`: raw bytes, then (if `endless`) an
/// unending stream of filler until the client hangs up.
fn camera(answer: fn(&str) -> (String, bool)) -> String {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap();
    std::thread::spawn(move || {
        for stream in listener.incoming().flatten() {
            std::thread::spawn(move || serve(stream, answer));
        }
    });
    format!("http://{addr}")
}

fn serve(mut stream: TcpStream, answer: fn(&str) -> (String, bool)) {
    let mut reader = BufReader::new(stream.try_clone().unwrap());
    let mut request = String::new();
    reader.read_line(&mut request).unwrap_or(0);
    // The headers, and a body if one was announced.
    let mut length = 0usize;
    loop {
        let mut line = String::new();
        if reader.read_line(&mut line).unwrap_or(0) == 0 || line == "\r\n" {
            break;
        }
        if let Some(v) = line.to_ascii_lowercase().strip_prefix("content-length:") {
            length = v.trim().parse().unwrap_or(0);
        }
    }
    let _ = reader
        .by_ref()
        .take(length as u64)
        .read_to_end(&mut Vec::new());
    let (head, endless) = answer(&request);
    if stream.write_all(head.as_bytes()).is_err() {
        return;
    }
    let filler = vec![b' '; 1 << 16];
    while endless && stream.write_all(&filler).is_ok() {}
}

fn client(base: &str) -> OscClient {
    OscClient::new(
        base,
        None,
        HttpTimeouts {
            request: Duration::from_secs(5),
            poll: Duration::from_millis(10),
            command: Duration::from_secs(10),
            download: Duration::from_secs(60),
            retry_budget: Duration::from_secs(1),
        },
    )
    .unwrap()
}

fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap()
}

#[test]
fn a_file_announced_at_64_gib_is_refused_before_any_allocation() {
    let base = camera(|_| {
        (
            "HTTP/1.1 200 OK\r\nContent-Length: 68719476736\r\nContent-Type: image/jpeg\r\n\r\n\u{ff}\u{d8}"
                .into(),
            false,
        )
    });
    let c = client(&base);
    let url = format!("{base}/files/100RICOH/R0010001.JPG");
    let e = runtime()
        .block_on(c.download(&url, &mut |_, _| {}))
        .unwrap_err();
    assert!(
        e.to_string().contains("68719476736 bytes"),
        "the error names the announced size: {e}"
    );
}

#[test]
fn an_endless_json_answer_is_cut_off() {
    let base = camera(|_| {
        (
            "HTTP/1.1 200 OK\r\nContent-Type: application/json\r\n\r\n{\"model\": \"".into(),
            true,
        )
    });
    let e = runtime().block_on(client(&base).info()).unwrap_err();
    assert!(matches!(e, ThetaError::Malformed { .. }), "{e}");
    assert!(e.to_string().contains("bytes or more"), "{e}");
}

#[test]
fn a_redirect_to_another_host_is_not_followed() {
    // The other host would answer with a picture; it must never be asked.
    let elsewhere = camera(|_| {
        (
            "HTTP/1.1 200 OK\r\nContent-Length: 4\r\n\r\nEVIL".into(),
            false,
        )
    });
    static TARGET: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    TARGET.set(elsewhere).unwrap();
    let base = camera(|_| {
        (
            format!(
                "HTTP/1.1 302 Found\r\nLocation: {}/files/x.JPG\r\nContent-Length: 0\r\n\r\n",
                TARGET.get().unwrap()
            ),
            false,
        )
    });
    let url = format!("{base}/files/100RICOH/R0010001.JPG");
    match runtime().block_on(client(&base).download(&url, &mut |_, _| {})) {
        Ok(bytes) => panic!("saved {} bytes from a redirect", bytes.len()),
        Err(e) => assert!(e.to_string().contains("302"), "{e}"),
    }
}
