fn main() {
    eprintln!("sdid: not built yet");
    std::process::exit(1);
}
