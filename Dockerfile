# Builds optistim and runs it. Until the daemon exists (issue 5) the default command renders
# the benchmark scene; mount ../shared at /shared for the trajectories.
FROM rust:1.95-bookworm AS build
WORKDIR /src
COPY . .
RUN cargo build --release --locked

FROM debian:bookworm-slim
COPY --from=build /src/target/release/optistim /usr/local/bin/optistim
COPY config /opt/optistim/config
WORKDIR /opt/optistim
ENTRYPOINT ["optistim"]
CMD ["render", "config/moon_lambert.toml", "--out", "/tmp/out"]
