// Loopback-only OpenAI-compatible chat server for a small local GGUF model.
//
// Endpoints (non-streaming):
//   POST /v1/chat/completions
//   GET  /v1/models
//   GET  /health
//
// Runtime: node-llama-cpp with its prebuilt CPU binary. It never downloads or
// builds llama.cpp here (build: "never", skipDownload: true, gpu: false).
//
// Configuration (all optional):
//   argv[2] or --port N, or LOCAL_LLM_PORT   port (default 8088); host is always 127.0.0.1
//   LOCAL_LLM_MODEL        path to the .gguf (default models/SmolLM2-135M-Instruct.Q4_1.gguf)
//   LOCAL_LLM_MODEL_ID     id reported by the API (default: file name without .gguf)
//   LOCAL_LLM_CTX          context size in tokens (default 4096)
//   LOCAL_LLM_THREADS      CPU threads for evaluation (default 1, see README)
//   LOCAL_LLM_MAX_TOKENS   max_tokens used when a request gives none (default 256)
//   LOCAL_LLM_MAX_BODY     request body limit in bytes (default 33554432)

import http from "node:http";
import path from "node:path";
import fs from "node:fs";
import crypto from "node:crypto";
import { fileURLToPath } from "node:url";

// Belt and braces: forbid any llama.cpp source download even if some code path asks for it.
process.env.NODE_LLAMA_CPP_SKIP_DOWNLOAD = "true";
const { getLlama, LlamaChat } = await import("node-llama-cpp");

const HERE = path.dirname(fileURLToPath(import.meta.url));
const HOST = "127.0.0.1";

function envInt(name, dflt, min = 0) {
    const raw = process.env[name];
    if (raw === undefined || raw === "") return dflt;
    const v = Number(raw);
    if (!Number.isInteger(v) || v < min) {
        console.error(`local-llm: ${name} must be an integer >= ${min}, got ${JSON.stringify(raw)}`);
        process.exit(2);
    }
    return v;
}

function parsePort() {
    const args = process.argv.slice(2);
    let raw = process.env.LOCAL_LLM_PORT || "8088";
    for (let i = 0; i < args.length; i++) {
        if (args[i] === "--port" && i + 1 < args.length) raw = args[++i];
        else if (args[i].startsWith("--port=")) raw = args[i].slice("--port=".length);
        else if (/^\d+$/.test(args[i])) raw = args[i];
        else {
            console.error(`local-llm: unknown argument ${JSON.stringify(args[i])} (usage: node server.mjs [PORT])`);
            process.exit(2);
        }
    }
    const port = Number(raw);
    if (!Number.isInteger(port) || port < 1 || port > 65535) {
        console.error(`local-llm: bad port ${JSON.stringify(raw)}`);
        process.exit(2);
    }
    return port;
}

const PORT = parsePort();
const MODEL_PATH = path.resolve(HERE, process.env.LOCAL_LLM_MODEL || "models/SmolLM2-135M-Instruct.Q4_1.gguf");
const MODEL_ID = process.env.LOCAL_LLM_MODEL_ID || path.basename(MODEL_PATH).replace(/\.gguf$/i, "");
const CTX = envInt("LOCAL_LLM_CTX", 4096, 256);
const THREADS = envInt("LOCAL_LLM_THREADS", 1, 1);
const DEFAULT_MAX_TOKENS = envInt("LOCAL_LLM_MAX_TOKENS", 256, 1);
const MAX_BODY = envInt("LOCAL_LLM_MAX_BODY", 32 * 1024 * 1024, 1024);

if (!fs.existsSync(MODEL_PATH)) {
    console.error(`local-llm: model file not found: ${MODEL_PATH}\nlocal-llm: run tools/local-llm/setup.sh first`);
    process.exit(1);
}

// ---------------------------------------------------------------- model ----

const tLoad0 = performance.now();
const llama = await getLlama({
    gpu: false,
    build: "never",
    skipDownload: true,
    usePrebuiltBinaries: true,
    progressLogs: false,
    maxThreads: THREADS,
    logLevel: "error",
});
const model = await llama.loadModel({ modelPath: MODEL_PATH, gpuLayers: 0 });
const context = await model.createContext({ contextSize: Math.min(CTX, model.trainContextSize || CTX), threads: THREADS, sequences: 1 });
const sequence = context.getSequence();
const chat = new LlamaChat({ contextSequence: sequence });
const loadMs = performance.now() - tLoad0;
const CREATED = Math.floor(Date.now() / 1000);
let jsonGrammar = null; // built lazily on first response_format json_object

// ------------------------------------------------------------- helpers ----

class BadRequest extends Error {
    constructor(message, param = null, code = null, status = 400) {
        super(message);
        this.param = param;
        this.code = code;
        this.status = status;
    }
}

function sendJson(res, status, body) {
    if (res.headersSent || res.destroyed) return;
    const data = JSON.stringify(body);
    res.writeHead(status, {
        "content-type": "application/json; charset=utf-8",
        "content-length": Buffer.byteLength(data),
    });
    res.end(data);
}

function sendError(res, status, message, { type = "invalid_request_error", param = null, code = null } = {}) {
    sendJson(res, status, { error: { message, type, param, code } });
}

function readBody(req) {
    return new Promise((resolve, reject) => {
        const chunks = [];
        let size = 0;
        req.on("data", (c) => {
            size += c.length;
            if (size > MAX_BODY) {
                reject(new BadRequest(`request body larger than ${MAX_BODY} bytes`, null, "body_too_large", 413));
                req.destroy();
                return;
            }
            chunks.push(c);
        });
        req.on("end", () => resolve(Buffer.concat(chunks).toString("utf8")));
        req.on("error", reject);
    });
}

const IGNORED_PART_TYPES = new Set(["image_url", "input_image", "image", "input_audio", "file"]);

// Text of a message's content: a string, null, or an array of parts. Non-text parts
// (images, audio, files) are accepted and ignored: the model is text-only.
function contentText(content, idx) {
    const param = `messages[${idx}].content`;
    if (content === null || content === undefined) return "";
    if (typeof content === "string") return content;
    if (!Array.isArray(content)) throw new BadRequest(`${param} must be a string or an array of content parts`, param);
    const texts = [];
    content.forEach((part, j) => {
        const p = `${param}[${j}]`;
        if (typeof part === "string") { texts.push(part); return; }
        if (part === null || typeof part !== "object" || typeof part.type !== "string")
            throw new BadRequest(`${p} must be an object with a string "type"`, p);
        if (part.type === "text" || part.type === "input_text") {
            if (typeof part.text !== "string") throw new BadRequest(`${p}.text must be a string`, `${p}.text`);
            texts.push(part.text);
        } else if (!IGNORED_PART_TYPES.has(part.type)) {
            throw new BadRequest(`${p}.type ${JSON.stringify(part.type)} is not supported`, `${p}.type`);
        }
    });
    return texts.join("\n");
}

function toChatHistory(messages) {
    if (!Array.isArray(messages) || messages.length === 0)
        throw new BadRequest("messages must be a non-empty array", "messages");
    const history = [];
    messages.forEach((m, i) => {
        if (m === null || typeof m !== "object" || Array.isArray(m))
            throw new BadRequest(`messages[${i}] must be an object`, `messages[${i}]`);
        const text = contentText(m.content, i);
        switch (m.role) {
            case "system":
            case "developer":
                history.push({ type: "system", text });
                break;
            case "user":
                history.push({ type: "user", text });
                break;
            case "assistant":
                history.push({ type: "model", response: [text] });
                break;
            default:
                throw new BadRequest(`messages[${i}].role must be one of system, developer, user, assistant`, `messages[${i}].role`);
        }
    });
    if (!history.some((h) => h.type === "user"))
        throw new BadRequest("messages must contain at least one user message", "messages");
    // A trailing assistant message is continued; otherwise start an empty model turn.
    if (history[history.length - 1].type !== "model") history.push({ type: "model", response: [] });
    return history;
}

function optNumber(body, key, { min = -Infinity, max = Infinity, integer = false } = {}) {
    const v = body[key];
    if (v === undefined || v === null) return undefined;
    if (typeof v !== "number" || !Number.isFinite(v) || (integer && !Number.isInteger(v)) || v < min || v > max)
        throw new BadRequest(`${key} must be ${integer ? "an integer" : "a number"}` +
            (max === Infinity ? ` >= ${min}` : ` in [${min}, ${max}]`), key);
    return v;
}

async function grammarFor(responseFormat) {
    if (responseFormat === undefined || responseFormat === null) return undefined;
    if (typeof responseFormat !== "object" || typeof responseFormat.type !== "string")
        throw new BadRequest("response_format must be an object with a string type", "response_format");
    switch (responseFormat.type) {
        case "text":
            return undefined;
        case "json_object":
            jsonGrammar ??= await llama.getGrammarFor("json");
            return jsonGrammar;
        case "json_schema": {
            const schema = responseFormat.json_schema?.schema;
            if (schema === null || typeof schema !== "object")
                throw new BadRequest("response_format.json_schema.schema must be an object", "response_format.json_schema.schema");
            try {
                return await llama.createGrammarForJsonSchema(schema);
            } catch (e) {
                throw new BadRequest(`unsupported JSON schema: ${e?.message ?? e}`, "response_format.json_schema.schema");
            }
        }
        default:
            throw new BadRequest(`response_format.type ${JSON.stringify(responseFormat.type)} is not supported`, "response_format.type");
    }
}

function countPromptTokens(history) {
    const { contextText } = chat.chatWrapper.generateContextState({ chatHistory: history });
    return contextText.tokenize(model.tokenizer).length;
}

// ----------------------------------------------------------- completion ----

async function completion(body, signal) {
    if (body === null || typeof body !== "object" || Array.isArray(body))
        throw new BadRequest("request body must be a JSON object");
    if (body.stream === true) throw new BadRequest("stream is not supported by this server", "stream");
    if (body.model !== undefined && typeof body.model !== "string") throw new BadRequest("model must be a string", "model");
    optNumber(body, "n", { min: 1, max: 1, integer: true }); // only n = 1 is supported
    const history = toChatHistory(body.messages);
    const maxTokens =
        optNumber(body, "max_completion_tokens", { min: 1, integer: true }) ??
        optNumber(body, "max_tokens", { min: 1, integer: true }) ??
        DEFAULT_MAX_TOKENS;
    const temperature = optNumber(body, "temperature", { min: 0, max: 2 }) ?? 1;
    const topP = optNumber(body, "top_p", { min: 0, max: 1 });
    const seed = optNumber(body, "seed", { min: -(2 ** 53), max: 2 ** 53, integer: true });
    const frequencyPenalty = optNumber(body, "frequency_penalty", { min: -2, max: 2 });
    const presencePenalty = optNumber(body, "presence_penalty", { min: -2, max: 2 });
    let stop = body.stop;
    if (stop === undefined || stop === null) stop = [];
    else if (typeof stop === "string") stop = [stop];
    else if (!Array.isArray(stop) || stop.some((s) => typeof s !== "string" || s === ""))
        throw new BadRequest("stop must be a string or an array of non-empty strings", "stop");
    const grammar = await grammarFor(body.response_format);

    const promptTokens = countPromptTokens(history);
    if (promptTokens + maxTokens > context.contextSize)
        throw new BadRequest(
            `prompt (${promptTokens} tokens) + max_tokens (${maxTokens}) exceeds the context size (${context.contextSize})`,
            "messages", "context_length_exceeded");

    // Every request starts from an empty context: no state carries over between requests.
    await sequence.clearHistory();
    let completionTokens = 0;
    const t0 = performance.now();
    const result = await chat.generateResponse(history, {
        maxTokens,
        temperature,
        ...(topP !== undefined ? { topP } : {}),
        // seed only matters when sampling (temperature > 0); greedy is deterministic anyway.
        ...(seed !== undefined ? { seed: ((seed % 2 ** 32) + 2 ** 32) % 2 ** 32 } : {}),
        ...(frequencyPenalty !== undefined || presencePenalty !== undefined
            ? { repeatPenalty: { frequencyPenalty: frequencyPenalty ?? 0, presencePenalty: presencePenalty ?? 0 } }
            : {}),
        ...(stop.length > 0 ? { customStopTriggers: stop } : {}),
        ...(grammar ? { grammar } : {}),
        signal,
        onToken: (tokens) => { completionTokens += tokens.length; },
    });
    const genMs = performance.now() - t0;
    const finishReason = result.metadata.stopReason === "maxTokens" ? "length" : "stop";
    console.error(`local-llm: prompt=${promptTokens} completion=${completionTokens} finish=${finishReason} ${genMs.toFixed(0)}ms`);
    return {
        id: "chatcmpl-" + crypto.randomBytes(12).toString("hex"),
        object: "chat.completion",
        created: Math.floor(Date.now() / 1000),
        model: MODEL_ID,
        choices: [
            {
                index: 0,
                message: { role: "assistant", content: result.response },
                logprobs: null,
                finish_reason: finishReason,
            },
        ],
        usage: {
            prompt_tokens: promptTokens,
            completion_tokens: completionTokens,
            total_tokens: promptTokens + completionTokens,
        },
    };
}

// One request at a time: a simple promise chain.
let queue = Promise.resolve();
function serialised(fn) {
    const run = queue.then(fn);
    queue = run.catch(() => {});
    return run;
}

// --------------------------------------------------------------- server ----

const server = http.createServer(async (req, res) => {
    const url = new URL(req.url ?? "/", `http://${HOST}`);
    const route = url.pathname.replace(/\/+$/, "") || "/";
    try {
        if (route === "/health") {
            if (req.method !== "GET" && req.method !== "HEAD") return sendError(res, 405, "use GET");
            return sendJson(res, 200, { status: "ok", model: MODEL_ID, context_size: context.contextSize, threads: THREADS });
        }
        if (route === "/v1/models") {
            if (req.method !== "GET") return sendError(res, 405, "use GET");
            return sendJson(res, 200, {
                object: "list",
                data: [{ id: MODEL_ID, object: "model", created: CREATED, owned_by: "local" }],
            });
        }
        if (route === "/v1/chat/completions") {
            if (req.method !== "POST") return sendError(res, 405, "use POST");
            const raw = await readBody(req);
            let body;
            try {
                body = JSON.parse(raw);
            } catch (e) {
                throw new BadRequest(`request body is not valid JSON: ${e.message}`);
            }
            const abort = new AbortController();
            res.on("close", () => { if (!res.writableFinished) abort.abort(new Error("client disconnected")); });
            const reply = await serialised(() => {
                if (abort.signal.aborted) throw abort.signal.reason;
                return completion(body, abort.signal);
            });
            return sendJson(res, 200, reply);
        }
        return sendError(res, 404, `no route for ${req.method} ${url.pathname}`, { type: "not_found_error" });
    } catch (e) {
        if (e instanceof BadRequest) return sendError(res, e.status, e.message, { param: e.param, code: e.code });
        if (res.destroyed) {
            console.error(`local-llm: request abandoned (${e?.message ?? e})`);
            return;
        }
        console.error("local-llm: internal error:", e);
        return sendError(res, 500, String(e?.message ?? e), { type: "server_error" });
    }
});

server.on("clientError", (err, socket) => {
    if (socket.writable) socket.end("HTTP/1.1 400 Bad Request\r\nconnection: close\r\n\r\n");
});

let closing = false;
async function shutdown(sig) {
    if (closing) return;
    closing = true;
    console.error(`local-llm: ${sig}, shutting down`);
    server.close();
    server.closeAllConnections?.();
    try { await llama.dispose(); } catch { /* exiting anyway */ }
    process.exit(0);
}
process.on("SIGINT", () => shutdown("SIGINT"));
process.on("SIGTERM", () => shutdown("SIGTERM"));

server.on("error", (e) => {
    console.error(`local-llm: cannot listen on ${HOST}:${PORT}: ${e.message}`);
    process.exit(1);
});
server.listen(PORT, HOST, () => {
    console.error(`local-llm: model ${MODEL_ID} (${path.relative(HERE, MODEL_PATH)}), ctx ${context.contextSize}, threads ${THREADS}, chat wrapper ${chat.chatWrapper.wrapperName}, loaded in ${loadMs.toFixed(0)} ms`);
    // The one line on stdout: the base URL (POST {base}/v1/chat/completions), printed once requests are accepted.
    console.log(`http://${HOST}:${PORT}`);
});
