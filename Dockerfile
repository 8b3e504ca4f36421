# Builds optistim and runs the daemon with its embedded default configuration, headless:
# frames are presented off-screen on Mesa's software Vulkan driver (or a GPU passed through),
# poses on 7878 (binary frames or JSON lines), HTTP on 7879 (dashboard, status, metrics).
#   docker build -t optistim . && docker run -p 7878:7878 -p 7879:7879 optistim
# Mount ../shared at /shared to replay its trajectories from inside the container.
FROM rust:1.95-bookworm AS build
WORKDIR /src
COPY . .
RUN cargo build --release --locked

FROM debian:bookworm-slim
RUN apt-get update \
 && apt-get install -y --no-install-recommends mesa-vulkan-drivers libvulkan1 \
 && rm -rf /var/lib/apt/lists/*
COPY --from=build /src/target/release/optistim /usr/local/bin/optistim
COPY config /opt/optistim/config
COPY calibration /opt/optistim/calibration
WORKDIR /opt/optistim
ENV XDG_RUNTIME_DIR=/tmp
EXPOSE 7878 7879
ENTRYPOINT ["optistim"]
# Inside a container the listeners bind all interfaces so that published ports reach them.
CMD ["serve", "--listen", "0.0.0.0:7878", "--http", "0.0.0.0:7879", "--present", "offscreen"]
