fn main() {
    eprintln!("sdictl: not built yet");
    std::process::exit(1);
}
