using System;
using System.Collections.Generic;
using System.Globalization;
using System.Linq;
using System.Net;
using System.Net.Http;
using System.Net.Http.Headers;
using System.Text;
using System.Threading.Tasks;

namespace Vista.Client
{
    /// <summary>
    /// The supervisor's HTTP API as a headset uses it: sign in, who am I, inspections, sync,
    /// pushing offline judgments and the scene. Errors throw <see cref="VistaApiException"/>
    /// (the server answered) or <see cref="HttpRequestException"/> /
    /// <see cref="TaskCanceledException"/> (no answer: offline or timed out). The returned tasks
    /// do not resume on the caller's synchronisation context; callers that touch UI state
    /// await them normally and continue on their own context.
    /// </summary>
    public sealed class VistaApi : IDisposable
    {
        const string JsonMediaType = "application/json";

        readonly HttpClient http;

        /// <summary>A client of the supervisor at <paramref name="baseUrl"/> (e.g.
        /// <c>https://vista.example:8000</c>) that accepts gzip-compressed answers.</summary>
        public VistaApi(string baseUrl)
            : this(baseUrl, CreateHandler())
        {
        }

        /// <summary>A client that sends through <paramref name="handler"/> (which it disposes).</summary>
        public VistaApi(string baseUrl, HttpMessageHandler handler)
        {
            if (string.IsNullOrEmpty(baseUrl))
            {
                throw new ArgumentException("give the supervisor's URL, e.g. http://host:8000");
            }
            http = new HttpClient(handler)
            {
                BaseAddress = new Uri(baseUrl.TrimEnd('/') + "/api/v1/"),
                Timeout = TimeSpan.FromSeconds(60),
            };
        }

        /// <summary>The handler the default constructor uses: gzip and deflate decompressed
        /// transparently (the sync answers large pages compressed).</summary>
        public static HttpClientHandler CreateHandler()
        {
            return new HttpClientHandler
            {
                AutomaticDecompression = DecompressionMethods.GZip | DecompressionMethods.Deflate,
            };
        }

        /// <summary>The bearer token sent with every request (set by <see cref="SignInAsync"/>,
        /// or set it to a device token).</summary>
        public string Token { get; set; }

        /// <summary>How long one request may take before it is abandoned.</summary>
        public TimeSpan Timeout
        {
            get { return http.Timeout; }
            set { http.Timeout = value; }
        }

        /// <summary><c>POST /auth/token</c>: signs in and keeps the token for later requests.</summary>
        public async Task<TokenInfo> SignInAsync(string username, string password)
        {
            var body = new Dictionary<string, object> { { "username", username }, { "password", password } };
            TokenInfo token = TokenInfo.FromJson(await SendJsonAsync(HttpMethod.Post, "auth/token", body).ConfigureAwait(false));
            Token = token.AccessToken;
            return token;
        }

        /// <summary><c>GET /me</c>: whom the token belongs to.</summary>
        public async Task<UserInfo> GetMeAsync()
        {
            return UserInfo.FromJson(await SendJsonAsync(HttpMethod.Get, "me", null).ConfigureAwait(false));
        }

        /// <summary><c>GET /inspections</c>: one page, from <paramref name="cursor"/> (null: the first).</summary>
        public async Task<InspectionPage> ListInspectionsAsync(string cursor = null, int? limit = null)
        {
            string path = "inspections" + Query(new KeyValuePair<string, string>("cursor", cursor), LimitParameter(limit));
            return InspectionPage.FromJson(await SendJsonAsync(HttpMethod.Get, path, null).ConfigureAwait(false));
        }

        /// <summary><c>GET /inspections/{id}</c>.</summary>
        public async Task<Inspection> GetInspectionAsync(long inspectionId)
        {
            string path = "inspections/" + inspectionId.ToString(CultureInfo.InvariantCulture);
            return Inspection.FromJson(await SendJsonAsync(HttpMethod.Get, path, null).ConfigureAwait(false));
        }

        /// <summary><c>GET /sync</c>: one page of what changed in an inspection after
        /// <paramref name="since"/> (null: a full sync from the start).</summary>
        public async Task<SyncPage> GetSyncPageAsync(long inspectionId, string since, int? limit = null)
        {
            string path = "sync" + Query(
                new KeyValuePair<string, string>("inspection", inspectionId.ToString(CultureInfo.InvariantCulture)),
                new KeyValuePair<string, string>("since", since),
                LimitParameter(limit));
            return SyncPage.FromJson(await SendJsonAsync(HttpMethod.Get, path, null).ConfigureAwait(false));
        }

        /// <summary><c>POST /sync/judgments</c>: one batch (at most 1000) of offline judgments.</summary>
        public async Task<PushResult> PushJudgmentsAsync(IList<OfflineJudgment> items)
        {
            var body = new Dictionary<string, object> { { "items", items.Select(i => i.ToJson()).ToList() } };
            return PushResult.FromJson(await SendJsonAsync(HttpMethod.Post, "sync/judgments", body).ConfigureAwait(false));
        }

        /// <summary><c>GET /inspections/{id}/scene.glb</c>; with the ETag of the copy held in
        /// <paramref name="ifNoneMatch"/> the answer is "not modified" while it is current.</summary>
        public async Task<SceneDownload> GetSceneAsync(long inspectionId, string ifNoneMatch)
        {
            string path = "inspections/" + inspectionId.ToString(CultureInfo.InvariantCulture) + "/scene.glb";
            using (var request = new HttpRequestMessage(HttpMethod.Get, path))
            {
                if (!string.IsNullOrEmpty(ifNoneMatch))
                {
                    request.Headers.TryAddWithoutValidation("If-None-Match", ifNoneMatch);
                }
                using (HttpResponseMessage response = await SendAsync(request).ConfigureAwait(false))
                {
                    byte[] body = await response.Content.ReadAsByteArrayAsync().ConfigureAwait(false);
                    if (response.StatusCode != HttpStatusCode.NotModified && !response.IsSuccessStatusCode)
                    {
                        throw ProblemOf(response, body);
                    }
                    IEnumerable<string> etags;
                    bool notModified = response.StatusCode == HttpStatusCode.NotModified;
                    return new SceneDownload
                    {
                        NotModified = notModified,
                        Bytes = notModified ? null : body,
                        ETag = response.Headers.TryGetValues("ETag", out etags) ? etags.FirstOrDefault() : null,
                    };
                }
            }
        }

        /// <summary><c>GET /jobs/{id}/scene.glb</c>: a finished job's scene (read it with
        /// <see cref="JobScene"/>, show it with glTFast).</summary>
        public async Task<byte[]> GetJobSceneAsync(long jobId)
        {
            string path = "jobs/" + jobId.ToString(CultureInfo.InvariantCulture) + "/scene.glb";
            using (var request = new HttpRequestMessage(HttpMethod.Get, path))
            using (HttpResponseMessage response = await SendAsync(request).ConfigureAwait(false))
            {
                byte[] body = await response.Content.ReadAsByteArrayAsync().ConfigureAwait(false);
                if (!response.IsSuccessStatusCode)
                {
                    throw ProblemOf(response, body);
                }
                return body;
            }
        }

        /// <summary>Releases the HTTP connection pool.</summary>
        public void Dispose()
        {
            http.Dispose();
        }

        async Task<Dictionary<string, object>> SendJsonAsync(HttpMethod method, string path, object body)
        {
            using (var request = new HttpRequestMessage(method, path))
            {
                request.Headers.Accept.Add(new MediaTypeWithQualityHeaderValue(JsonMediaType));
                if (body != null)
                {
                    request.Content = new StringContent(Json.Serialize(body), Encoding.UTF8, JsonMediaType);
                }
                using (HttpResponseMessage response = await SendAsync(request).ConfigureAwait(false))
                {
                    byte[] answer = await response.Content.ReadAsByteArrayAsync().ConfigureAwait(false);
                    if (!response.IsSuccessStatusCode)
                    {
                        throw ProblemOf(response, answer);
                    }
                    return Json.ParseObject(Encoding.UTF8.GetString(answer));
                }
            }
        }

        Task<HttpResponseMessage> SendAsync(HttpRequestMessage request)
        {
            if (!string.IsNullOrEmpty(Token))
            {
                request.Headers.Authorization = new AuthenticationHeaderValue("Bearer", Token);
            }
            return http.SendAsync(request);
        }

        /// <summary>The error of an answer: its problem document's title and detail, or a
        /// sentence of our own when the body is not one (e.g. a proxy's HTML page).</summary>
        static VistaApiException ProblemOf(HttpResponseMessage response, byte[] body)
        {
            int status = (int)response.StatusCode;
            string title = response.ReasonPhrase;
            string detail = null;
            try
            {
                Dictionary<string, object> problem = Json.ParseObject(Encoding.UTF8.GetString(body));
                title = problem.GetString("title") ?? title;
                detail = problem.GetString("detail");
            }
            catch (FormatException)
            {
                // Not a problem document (e.g. a proxy's HTML page): described below.
            }
            if (string.IsNullOrEmpty(detail))
            {
                detail = "The supervisor answered " + status + " " + response.ReasonPhrase
                    + " to " + response.RequestMessage.RequestUri + ".";
            }
            return new VistaApiException(status, title, detail);
        }

        static KeyValuePair<string, string> LimitParameter(int? limit)
        {
            return new KeyValuePair<string, string>(
                "limit", limit.HasValue ? limit.Value.ToString(CultureInfo.InvariantCulture) : null);
        }

        static string Query(params KeyValuePair<string, string>[] parameters)
        {
            var given = parameters.Where(p => p.Value != null)
                .Select(p => p.Key + "=" + Uri.EscapeDataString(p.Value))
                .ToArray();
            return given.Length == 0 ? "" : "?" + string.Join("&", given);
        }
    }
}
