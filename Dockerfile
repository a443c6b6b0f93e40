# candeck: the gateway and dashboard in a small image (docs/deployment.md, "Docker").
#
# Build stage: the release binary, built and then smoke-tested by
# scripts/container-steps, the same script scripts/test runs outside Docker
# (tests/packaging.rs checks that these RUN lines are its steps).
FROM rust:1.95-slim-bookworm AS build
# curl: the smoke test asks the gateway for /api/v1/health and the dashboard.
RUN apt-get update \
    && apt-get install -y --no-install-recommends curl \
    && rm -rf /var/lib/apt/lists/*
WORKDIR /src
# Only what `cargo build --release --locked` reads: the manifest and lock
# file, the sources (the binary's and the workspace's crates), the templates and static files the binary embeds
# (askama.toml, web/), the built-in EDS files (include_str!), and benches/
# because Cargo.toml names its [[bench]] targets.
COPY Cargo.toml Cargo.lock askama.toml ./
COPY src ./src
COPY crates ./crates
COPY web ./web
COPY eds ./eds
COPY benches ./benches
COPY scripts/container-steps ./scripts/container-steps
RUN scripts/container-steps build
RUN scripts/container-steps install
RUN scripts/container-steps smoke dist/candeck

# Runtime stage: Debian slim (the binary links glibc; same release as the
# build stage), the binary and curl for the health check.
FROM debian:bookworm-slim
# curl answers HEALTHCHECK: a tool every operator knows, about 1 MB with its
# libraries, rather than a health-check mode inside the gateway binary.
RUN apt-get update \
    && apt-get install -y --no-install-recommends curl \
    && rm -rf /var/lib/apt/lists/* \
    && groupadd --system --gid 10001 candeck \
    && useradd --system --uid 10001 --gid candeck --home-dir /var/lib/candeck --shell /usr/sbin/nologin candeck \
    && mkdir -p /var/lib/candeck \
    && chown candeck:candeck /var/lib/candeck
COPY --from=build /src/dist/candeck /usr/local/bin/candeck
USER 10001:10001
WORKDIR /var/lib/candeck
# --data-dir: the history (SQLite), recordings and what virtual devices save.
VOLUME ["/var/lib/candeck"]
# 8080: HTTP (dashboard, REST, WebSocket); 29536: socketcand (candeck vbus, --share).
EXPOSE 8080 29536
# A vbus service has no HTTP: docker-compose.yml gives it its own check.
HEALTHCHECK --interval=10s --timeout=3s --start-period=5s --retries=3 \
    CMD ["curl", "-fsS", "-o", "/dev/null", "http://127.0.0.1:8080/api/v1/health"]
ENTRYPOINT ["candeck"]
# Listening beyond loopback without tokens needs --insecure: the compose demo
# publishes the port on the host's loopback only; give tokens
# (CANDECK_TOKENS) for anything else (docs/security.md).
CMD ["serve", "--listen", "0.0.0.0:8080", "--data-dir", "/var/lib/candeck", "--insecure"]
