// Drives built pages of `python -m unilab_jax.web` in headless Chromium (playwright-core, the system's
// Chromium): `node tests/web_driver.mjs JOBS.json` prints a JSON list with one result per job.
//
// A job: {"dir": built page, "query": "?speed=0", "actions": [...]}; actions run in order:
//   {"eval": "JS expression"}          its value (awaited) is appended to the job's results
//   {"down": "ArrowUp"} / {"up": ...}  a key pressed / released (trusted input events)
//   {"wait": "JS expression"}          until it is truthy
//   {"screenshot": "path.png"}
// The page is served from the job's folder through request interception (no server, no port).
import { chromium } from "playwright-core";
import fs from "node:fs";
import path from "node:path";

const TYPES = { ".html": "text/html", ".js": "text/javascript", ".mjs": "text/javascript", ".json": "application/json",
                ".wasm": "application/wasm", ".xml": "text/xml", ".onnx": "application/octet-stream" };
const ORIGIN = "http://unilab.invalid";

const jobs = JSON.parse(fs.readFileSync(process.argv[2], "utf8"));
const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM || "/usr/bin/chromium",
  args: ["--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--disable-quic", "--no-first-run"],
});
const results = [];
try {
  for (const job of jobs) {
    const page = await browser.newPage({ viewport: { width: 960, height: 600 } });
    const errors = [];
    page.on("pageerror", (e) => errors.push(String(e)));
    page.on("console", (m) => { if (m.type() === "error") errors.push(m.text()); });
    await page.route(ORIGIN + "/**", (route) => {
      const rel = decodeURIComponent(new URL(route.request().url()).pathname).replace(/^\/+/, "") || "index.html";
      const file = path.join(job.dir, rel);
      if (!file.startsWith(path.resolve(job.dir)) || !fs.existsSync(file)) return route.fulfill({ status: 404 });
      return route.fulfill({ path: file, contentType: TYPES[path.extname(file)] || "application/octet-stream" });
    });
    const out = { values: [], errors };
    try {
      await page.goto(ORIGIN + "/index.html" + (job.query || ""));
      await page.waitForFunction("window.unilab && (window.unilab.ready || window.unilab.error)", null,
                                 { timeout: 60000 });
      const error = await page.evaluate("window.unilab.error");
      if (error) throw new Error(error);
      for (const a of job.actions) {
        if ("eval" in a) out.values.push(await page.evaluate(a.eval));
        else if ("down" in a) await page.keyboard.down(a.down);
        else if ("up" in a) await page.keyboard.up(a.up);
        else if ("wait" in a) await page.waitForFunction(a.wait, null, { timeout: 60000, polling: 20 });
        else if ("screenshot" in a) await page.screenshot({ path: a.screenshot });
        else throw new Error("unknown action " + JSON.stringify(a));
      }
    } catch (e) {
      errors.push(String(e));
    }
    results.push(out);
    await page.close();
  }
} finally {
  await browser.close();
}
process.stdout.write(JSON.stringify(results));
