using System;

namespace Vista.Client
{
    /// <summary>The supervisor answered with an error: an RFC 9457 problem document
    /// (<c>{"type", "title", "status", "detail"}</c>). <see cref="Exception.Message"/> is the
    /// detail, a sentence a person can act on.</summary>
    public sealed class VistaApiException : Exception
    {
        /// <summary>The HTTP status (e.g. 401, 404, 422).</summary>
        public int Status { get; private set; }

        /// <summary>The problem's short title (e.g. "Not signed in").</summary>
        public string Title { get; private set; }

        /// <summary>What went wrong and what to do about it.</summary>
        public string Detail { get; private set; }

        /// <summary>An error of the given status, title and detail.</summary>
        public VistaApiException(int status, string title, string detail)
            : base(detail)
        {
            Status = status;
            Title = title;
            Detail = detail;
        }
    }
}
