//! Webhooks: when a job ends, its document is POSTed to the job's
//! `callback_url`, signed per the Standard Webhooks specification.
//!
//! - **Durable.** The delivery row is inserted in the same transaction as
//!   the job's terminal update ([`schedule`]), so a crash can neither lose a
//!   webhook nor send one for an end that rolled back. Any worker process
//!   delivers due rows; a delivery is claimed by bumping its `next_at` with
//!   a compare-and-set, so two processes never send the same attempt.
//! - **Retries** with exponential backoff and full jitter (0.5 s doubling,
//!   capped at an hour) until a 2xx, for at most [`MAX_ATTEMPTS`] attempts.
//!   The `webhook-id` stays the same across retries so receivers can
//!   deduplicate.
//! - **Signature.** `webhook-signature: v1,<base64(HMAC-SHA256(key,
//!   "{webhook-id}.{webhook-timestamp}.{body}"))>` where the key is the
//!   base64-decoded part of the `whsec_…` secret.
//! - **SSRF guard.** A callback URL must be http(s) and resolve only to
//!   public addresses (no loopback, private, link-local, unique-local,
//!   multicast or unspecified ranges) unless `--allow-private-callbacks`.
//!   The check runs at `POST /v1/jobs` and again at every send, and the
//!   request is pinned to the addresses just checked (DNS rebinding cannot
//!   swap them in between); redirects are not followed.

use std::net::{IpAddr, SocketAddr};
use std::time::Duration;

use base64::Engine;
use base64::engine::general_purpose::STANDARD;
use hmac::{KeyInit, Mac};
use sqlx::{Any, Row, Transaction};

use super::Services;
use super::queue::JobRow;
use crate::store::{new_id, now_ms};

/// Delivery attempts before a webhook is given up.
pub const MAX_ATTEMPTS: i64 = 10;

/// Schedules the webhook of a job that just ended (inside the transaction
/// of its terminal update).
pub async fn schedule(tx: &mut Transaction<'_, Any>, row: &JobRow) -> Result<(), sqlx::Error> {
    let Some(url) = &row.callback_url else {
        return Ok(());
    };
    let body = serde_json::to_string(&row.info()).expect("job documents serialise");
    let now = now_ms();
    sqlx::query(
        "INSERT INTO webhook_deliveries (id, job_id, url, body, state, attempts, next_at, created_at) \
         VALUES ($1, $2, $3, $4, 'pending', 0, $5, $5)",
    )
    .bind(format!("msg_{}", new_id()))
    .bind(&row.id)
    .bind(url)
    .bind(body)
    .bind(now)
    .execute(&mut **tx)
    .await?;
    Ok(())
}

/// Deletes the records of deliveries that are done (delivered or given
/// up) and whose job is gone (deleted or expired); returns how many went.
/// A pending delivery of a deleted job stays until it is done: the job's
/// end is still announced.
pub async fn purge_done_without_job(db: &crate::store::Db) -> Result<u64, sqlx::Error> {
    Ok(sqlx::query(
        "DELETE FROM webhook_deliveries WHERE state <> 'pending' \
         AND job_id NOT IN (SELECT id FROM jobs)",
    )
    .execute(&db.writer)
    .await?
    .rows_affected())
}

/// Parses a `whsec_<base64>` secret into the HMAC key.
pub fn parse_secret(secret: &str) -> Result<Vec<u8>, String> {
    let b64 = secret
        .strip_prefix("whsec_")
        .ok_or("the webhook secret must start with whsec_")?;
    let key = STANDARD
        .decode(b64)
        .map_err(|e| format!("the webhook secret is not base64 after whsec_: {e}"))?;
    if key.len() < 16 {
        return Err("the webhook secret must carry at least 16 bytes".into());
    }
    Ok(key)
}

/// The signing key: from `--webhook-secret`, else from
/// `{data_dir}/webhook-secret`, else a new random secret saved there. The
/// log names the file the operator reads it from, never the secret: logs
/// are often shipped to systems that more people can read.
pub fn load_or_create_key(settings: &crate::config::Settings) -> anyhow::Result<Vec<u8>> {
    if let Some(secret) = &settings.webhook_secret {
        return parse_secret(secret.trim()).map_err(anyhow::Error::msg);
    }
    let path = settings.data_dir.join("webhook-secret");
    if let Ok(text) = std::fs::read_to_string(&path) {
        return parse_secret(text.trim()).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()));
    }
    let mut key = [0u8; 32];
    key[..16].copy_from_slice(uuid::Uuid::new_v4().as_bytes());
    key[16..].copy_from_slice(uuid::Uuid::new_v4().as_bytes());
    let secret = format!("whsec_{}", STANDARD.encode(key));
    std::fs::create_dir_all(&settings.data_dir)?;
    crate::files::write_atomic(&path, format!("{secret}\n").as_bytes())?;
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o600))?;
    }
    tracing::warn!(
        file = %path.display(),
        "generated a webhook signing secret; receivers verify signatures with the secret in this file"
    );
    Ok(key.to_vec())
}

/// The `webhook-signature` header value.
pub fn sign(key: &[u8], id: &str, timestamp: i64, body: &str) -> String {
    let mut mac =
        hmac::Hmac::<sha2::Sha256>::new_from_slice(key).expect("HMAC takes any key length");
    mac.update(format!("{id}.{timestamp}.{body}").as_bytes());
    format!("v1,{}", STANDARD.encode(mac.finalize().into_bytes()))
}

/// Whether an address is publicly routable (not loopback, private,
/// link-local, unique-local, shared, multicast, documentation or
/// unspecified).
pub fn is_public(ip: IpAddr) -> bool {
    match ip {
        IpAddr::V4(v4) => {
            let o = v4.octets();
            !(v4.is_loopback()
                || v4.is_private()
                || v4.is_link_local()
                || v4.is_unspecified()
                || v4.is_broadcast()
                || v4.is_documentation()
                || v4.is_multicast()
                || o[0] == 0
                || (o[0] == 100 && (o[1] & 0xc0) == 64)
                || (o[0] == 198 && (o[1] & 0xfe) == 18))
        }
        IpAddr::V6(v6) => {
            if let Some(v4) = v6.to_ipv4_mapped() {
                return is_public(IpAddr::V4(v4));
            }
            !(v6.is_loopback()
                || v6.is_unspecified()
                || v6.is_unique_local()
                || v6.is_unicast_link_local()
                || v6.is_multicast())
        }
    }
}

/// Checks a callback URL and resolves it; the addresses to connect to.
pub async fn resolve_callback(
    url: &str,
    allow_private: bool,
) -> Result<(url::Url, Vec<SocketAddr>), String> {
    let parsed = url::Url::parse(url).map_err(|e| format!("callback_url is not a URL: {e}"))?;
    if !matches!(parsed.scheme(), "http" | "https") {
        return Err("callback_url must be an http or https URL".into());
    }
    let host = parsed
        .host_str()
        .ok_or("callback_url has no host")?
        .trim_start_matches('[')
        .trim_end_matches(']')
        .to_owned();
    let port = parsed
        .port_or_known_default()
        .ok_or("callback_url has no port")?;
    let addrs: Vec<SocketAddr> = tokio::time::timeout(
        Duration::from_secs(5),
        tokio::net::lookup_host((host.as_str(), port)),
    )
    .await
    .map_err(|_| format!("resolving {host} timed out"))?
    .map_err(|e| format!("cannot resolve {host}: {e}"))?
    .collect();
    if addrs.is_empty() {
        return Err(format!("{host} resolves to no address"));
    }
    if !allow_private && let Some(bad) = addrs.iter().find(|a| !is_public(a.ip())) {
        return Err(format!(
            "callback_url resolves to a non-public address ({}); refused",
            bad.ip()
        ));
    }
    Ok((parsed, addrs))
}

struct Due {
    id: String,
    url: String,
    body: String,
    attempts: i64,
}

/// Delivers due webhooks until the task is aborted.
pub async fn deliver_loop(services: Services) {
    loop {
        if let Err(e) = deliver_due(&services).await {
            tracing::warn!(error = %e, "webhook delivery round failed");
        }
        tokio::select! {
            _ = services.hub.webhooks.notified() => {}
            _ = tokio::time::sleep(Duration::from_millis(500)) => {}
        }
    }
}

async fn deliver_due(services: &Services) -> Result<(), sqlx::Error> {
    let now = now_ms();
    let rows = sqlx::query(
        "SELECT id, url, body, attempts, next_at FROM webhook_deliveries \
         WHERE state = 'pending' AND next_at <= $1 ORDER BY next_at LIMIT 16",
    )
    .bind(now)
    .fetch_all(&services.db.pool)
    .await?;
    for row in rows {
        let id: String = row.try_get("id")?;
        let next_at: i64 = row.try_get("next_at")?;
        // Claim: push next_at out of reach of other processes while we send.
        let claimed = sqlx::query(
            "UPDATE webhook_deliveries SET next_at = $3, attempts = attempts + 1 \
             WHERE id = $1 AND next_at = $2 AND state = 'pending'",
        )
        .bind(&id)
        .bind(next_at)
        .bind(now + 120_000)
        .execute(&services.db.writer)
        .await?
        .rows_affected();
        if claimed != 1 {
            continue;
        }
        let due = Due {
            id,
            url: row.try_get("url")?,
            body: row.try_get("body")?,
            attempts: row.try_get::<i64, _>("attempts")? + 1,
        };
        let services = services.clone();
        tokio::spawn(async move {
            let result = send(&services, &due).await;
            if let Err(e) = record(&services, &due, result).await {
                tracing::warn!(delivery = %due.id, error = %e, "recording a webhook delivery failed");
            }
        });
    }
    Ok(())
}

async fn send(services: &Services, due: &Due) -> Result<(), String> {
    let (url, addrs) =
        resolve_callback(&due.url, services.settings.allow_private_callbacks).await?;
    let host = url.host_str().unwrap_or_default().to_owned();
    let client = crate::tls::client_builder()
        .redirect(reqwest::redirect::Policy::none())
        .timeout(Duration::from_secs(10))
        .resolve_to_addrs(&host, &addrs)
        .build()
        .map_err(|e| e.to_string())?;
    let timestamp = now_ms() / 1000;
    let signature = sign(&services.webhook_key, &due.id, timestamp, &due.body);
    let response = client
        .post(url)
        .header("content-type", "application/json")
        .header("webhook-id", &due.id)
        .header("webhook-timestamp", timestamp.to_string())
        .header("webhook-signature", signature)
        .body(due.body.clone())
        .send()
        .await
        .map_err(|e| e.to_string())?;
    if response.status().is_success() {
        Ok(())
    } else {
        Err(format!("receiver answered {}", response.status()))
    }
}

async fn record(
    services: &Services,
    due: &Due,
    result: Result<(), String>,
) -> Result<(), sqlx::Error> {
    match result {
        Ok(()) => {
            tracing::info!(delivery = %due.id, attempts = due.attempts, "webhook delivered");
            sqlx::query("UPDATE webhook_deliveries SET state = 'delivered', last_error = NULL WHERE id = $1")
                .bind(&due.id)
                .execute(&services.db.writer)
                .await?;
        }
        Err(e) if due.attempts >= MAX_ATTEMPTS => {
            tracing::warn!(delivery = %due.id, error = %e, "webhook given up");
            sqlx::query(
                "UPDATE webhook_deliveries SET state = 'failed', last_error = $2 WHERE id = $1",
            )
            .bind(&due.id)
            .bind(e)
            .execute(&services.db.writer)
            .await?;
        }
        Err(e) => {
            let delay = super::backoff_ms(due.attempts as u32, 500, 3_600_000);
            tracing::info!(delivery = %due.id, error = %e, delay_ms = delay, "webhook failed; will retry");
            sqlx::query(
                "UPDATE webhook_deliveries SET next_at = $2, last_error = $3 WHERE id = $1",
            )
            .bind(&due.id)
            .bind(now_ms() + delay as i64)
            .bind(e)
            .execute(&services.db.writer)
            .await?;
            services.hub.webhooks.notify_one();
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use std::io::Write;
    use std::sync::{Arc, Mutex};

    use super::*;

    /// Collects what a subscriber writes.
    #[derive(Clone, Default)]
    struct Captured(Arc<Mutex<Vec<u8>>>);

    impl Write for Captured {
        fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
            self.0.lock().unwrap().extend_from_slice(buf);
            Ok(buf.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    #[test]
    fn a_generated_secret_is_logged_by_file_never_by_value() {
        // Regression: the WARN line at start carried the `whsec_` value.
        let dir = tempfile::tempdir().unwrap();
        let settings = crate::config::Settings::with_data_dir(dir.path());
        let log = Captured::default();
        let writer = log.clone();
        let subscriber = tracing_subscriber::fmt()
            .with_writer(move || writer.clone())
            .with_ansi(false)
            .finish();
        let key = tracing::subscriber::with_default(subscriber, || {
            super::load_or_create_key(&settings).unwrap()
        });
        let secret = std::fs::read_to_string(dir.path().join("webhook-secret")).unwrap();
        assert_eq!(super::parse_secret(secret.trim()).unwrap(), key);
        let text = String::from_utf8(log.0.lock().unwrap().clone()).unwrap();
        assert!(text.contains("webhook-secret"), "{text}");
        assert!(!text.contains(secret.trim()), "{text}");
        assert!(!text.contains("whsec_"), "{text}");
    }

    #[test]
    fn signature_matches_the_standard_webhooks_example() {
        // The example from the Standard Webhooks specification.
        let key = parse_secret("whsec_MfKQ9r8GKYqrTwjUPD8ILPZIo2LaLaSw").unwrap();
        let body = r#"{"test": 2432232314}"#;
        assert_eq!(
            sign(&key, "msg_p5jXN8AQM9LWM0D4loKWxJek", 1614265330, body),
            "v1,g0hM9SsE+OTPJTGt/tmIKtSyZlE3uFJELVlNIOLJ1OE="
        );
        assert!(parse_secret("nope").is_err());
    }

    #[test]
    fn private_ranges_are_not_public() {
        for ip in [
            "127.0.0.1",
            "10.1.2.3",
            "172.16.0.1",
            "192.168.1.1",
            "169.254.169.254",
            "0.0.0.0",
            "100.64.0.1",
            "::1",
            "fe80::1",
            "fd00::1",
            "::ffff:127.0.0.1",
            "224.0.0.1",
        ] {
            assert!(!is_public(ip.parse().unwrap()), "{ip}");
        }
        for ip in ["93.184.216.34", "2606:4700::1111", "8.8.8.8"] {
            assert!(is_public(ip.parse().unwrap()), "{ip}");
        }
    }

    #[tokio::test]
    async fn loopback_callbacks_are_refused_unless_allowed() {
        assert!(
            resolve_callback("http://127.0.0.1:9/x", false)
                .await
                .is_err()
        );
        assert!(
            resolve_callback("http://localhost:9/x", false)
                .await
                .is_err()
        );
        assert!(resolve_callback("ftp://example.com/", true).await.is_err());
        assert!(resolve_callback("http://127.0.0.1:9/x", true).await.is_ok());
    }
}
