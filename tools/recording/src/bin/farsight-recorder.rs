//! The recorder as a graph node (`stage = "recorder"`): wiring only; the
//! config and its edges are `farsight_recording::node`, the loop
//! `farsight_recording::record`.

use farsight_interfaces::transport::ipc::Bus;
use farsight_recording::node::RecorderConfig;
use farsight_recording::record::{record, RecordOptions};
use farsight_recording::write::RecordingWriter;

fn main() {
    farsight_stage::run_main("recorder", run);
}

fn run() -> Result<(), Box<dyn std::error::Error>> {
    let args = farsight_stage::StageArgs::parse("recorder")?;
    farsight_stage::init_tracing(args.log_format);
    let config: RecorderConfig = farsight_stage::load_config(args.config.as_deref())?;
    let bus = Bus::open(&args.instance)?;
    let out = config.out_path();
    let writer = RecordingWriter::create_with_options(&out, &config.writer_options())?;
    let opts = RecordOptions {
        patterns: config.topics.clone(),
        instance: Some(args.instance.clone()),
        ack: config.ack.clone(),
        ..Default::default()
    };
    tracing::info!(
        out = %out.display(),
        topics = ?config.topics,
        chunk_max_s = config.chunk_max_s,
        chunk_max_bytes = config.chunk_max_bytes,
        "recording"
    );
    let report = record(&bus, writer, &opts, || {
        farsight_stage::announce_ready(&args.instance)
    })?;
    for (topic, r) in &report {
        tracing::info!(
            topic,
            messages = r.written.messages,
            skipped = ?r.skipped,
            foxglove_dropped = r.written.foxglove_dropped,
            "recorded"
        );
    }
    Ok(())
}
