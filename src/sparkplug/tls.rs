//! TLS for `mqtts://`: rustls with the ring provider, the broker checked
//! against the CA file given (`mqtt_ca_file`), and a client certificate
//! when one is given (`mqtt_client_cert`, `mqtt_client_key`).

use std::sync::Arc;

use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, PrivateKeyDer};
use rustls::{ClientConfig, RootCertStore};

use super::config::TlsFiles;

/// The rustls client configuration of these files.
pub fn client_config(files: &TlsFiles) -> Result<ClientConfig, String> {
    let ca_file = files
        .ca_file
        .as_ref()
        .ok_or("mqtts:// needs mqtt_ca_file")?;
    let mut roots = RootCertStore::empty();
    let certs = CertificateDer::pem_file_iter(ca_file)
        .map_err(|err| format!("mqtt_ca_file {}: {err}", ca_file.display()))?;
    for cert in certs {
        let cert = cert.map_err(|err| format!("mqtt_ca_file {}: {err}", ca_file.display()))?;
        roots
            .add(cert)
            .map_err(|err| format!("mqtt_ca_file {}: {err}", ca_file.display()))?;
    }
    if roots.is_empty() {
        return Err(format!(
            "mqtt_ca_file {}: no certificate in it",
            ca_file.display()
        ));
    }
    let builder =
        ClientConfig::builder_with_provider(Arc::new(rustls::crypto::ring::default_provider()))
            .with_safe_default_protocol_versions()
            .map_err(|err| format!("TLS: {err}"))?
            .with_root_certificates(roots);
    match (&files.client_cert, &files.client_key) {
        (Some(cert), Some(key)) => {
            let chain = CertificateDer::pem_file_iter(cert)
                .and_then(|certs| certs.collect::<Result<Vec<_>, _>>())
                .map_err(|err| format!("mqtt_client_cert {}: {err}", cert.display()))?;
            let key = PrivateKeyDer::from_pem_file(key)
                .map_err(|err| format!("mqtt_client_key {}: {err}", key.display()))?;
            builder
                .with_client_auth_cert(chain, key)
                .map_err(|err| format!("mqtt_client_cert: {err}"))
        }
        _ => Ok(builder.with_no_client_auth()),
    }
}
